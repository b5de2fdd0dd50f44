"""planar-pose training side, one sub-package per pipeline step.

* `train.synth`: synthetic images of the object (render, backgrounds, data sets);
* `train.real`: real photographs (corners, calibration, labelling, real data sets);
* `train.network`: the CNN (model, training loop, evaluation, export);
* `train.compare`: the feature baseline and the comparison report;
* `train.commands`: the `planar-pose` command line;
* `train/assets/`: the data files (profiles, backgrounds, real photographs).

The rules they share (object frame, regions, profiles, data-set format, input contract) live
in the torch-free `service.core`. Modules that need torch import it themselves; importing
this package does not.
"""
