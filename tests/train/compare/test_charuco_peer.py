"""The ChArUco detector peer (train/compare/charuco_peer.py) and its place among the peers."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from charuco_views import SPEC, K, view

from service.core.regions import pose_class
from train.compare.charuco_peer import CharucoPeer
from train.compare.peers import DETECTORS, default_peers, peer_name
from train.real.calibration import Camera


@pytest.mark.parametrize("centre", [(12.0, 9.0, 45.0), (-15.0, -8.0, 75.0)])
def test_the_peer_finds_the_class_of_a_view(centre) -> None:
    small = cv2.resize(view(centre), (640, 360), interpolation=cv2.INTER_AREA)
    camera = Camera(K, np.zeros(5), (1280, 720)).scaled((640, 360))
    pred = CharucoPeer(SPEC, 60.0, enlarge=1).predict(small, camera)
    assert pred.label == int(pose_class(centre, 60.0)) and pred.features == "charuco"
    blank = CharucoPeer(SPEC, 60.0).predict(np.full((120, 160, 3), 90, np.uint8), camera)
    assert blank.label == 0 and blank.reason == "no board found"


def test_the_detectors_are_named_peers() -> None:
    assert peer_name("charuco") == "opencv-charuco" and peer_name("sift") == "baseline-sift"
    assert set(DETECTORS) <= set(default_peers())
    with pytest.raises(ValueError, match="enlarge"):
        CharucoPeer(SPEC, 60.0, enlarge=0.5)
