"""The comparison step: the network vs the classical peers (`planar-pose compare`, `baseline`).

* `run`: orchestration (what is measured on which data set, which files are written);
* `peers`: the peers by name: `baseline` (SIFT / ORB features, RANSAC, PnP) and
  `chessboard_peer` (OpenCV's chessboard detector, PnP);
* `sets`: data set splits, manifests, model cards, the stored photos behind real sets;
* `detection`: whole image / sliding windows / object proposals through the service;
* `report`: the Markdown writers, one per section; `plots`: the PNGs.
"""
