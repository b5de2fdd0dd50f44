"""The method's rules, written once: torch-free and HTTP-free, imported by both sides.

* `frame`: the object frame and the order of its four corners (also the ONNX `corners` order);
* `regions`: the region rule (camera centre -> class 0..8) and the classes in words;
* `geometry`: pinhole geometry as pure numpy functions (look-at, homographies, pose);
* `inputs`: the network input sizes and the SPEC camera at those sizes;
* `preprocess`: image bytes -> the network's input (decoding, turning, resizing, pixel aspect);
* `blur`: the SPEC blur levels of the data sets;
* `onnx_contract`: the exported graph's input and output names and shapes;
* `profile`: object profiles (texture, size, region geometry, rendering ranges);
* `dataset`: the data-set folder format (labels.csv columns, splits, manifest.json).

`train` and `service` import this package; it imports neither (import-linter, `.importlinter`).
"""
