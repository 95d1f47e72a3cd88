"""The micro-gripping application (§2): locating, the closed loop, the command line."""

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

import slmlab
from slmlab.gripping import Scene, build_gripper_model, grip, locate_gripper, locate_wire, render_scene, wire_mask


def test_gripper_and_wire_are_located_to_a_tenth_of_a_pixel():
    m = slmlab.preset("paper")
    sc = replace(Scene(), object_rotation_deg=4.0)
    start = sc.grip_point() + np.asarray(sc.gripper_tip_start_mm)
    for tip in (start, sc.grip_point()):  # far from the wire, and on it
        model = build_gripper_model(m, sc, tip)
        for side in "lr":
            first = render_scene(m, sc, start, side, np.random.default_rng(1))
            _, line, grip_px = locate_wire(first, m, sc, side)
            img = render_scene(m, sc, tip, side, np.random.default_rng(2))
            found = locate_gripper(img, model, side, expected_px=model.reference_tip_px[side],
                                   mask=wire_mask(img.shape, line))
            assert np.hypot(*(found - m.project_view(np.atleast_2d(tip), side)[0])) < 0.15
            # the wire's centreline passes through the true gripping position
            (mu, d) = line
            true = m.project_view(np.atleast_2d(sc.grip_point()), side)[0]
            assert abs((true - mu) @ np.array([-d[1], d[0]])) < 0.1


@pytest.mark.parametrize("seed", [1, 2])
def test_an_episode_grips_within_the_papers_precision(seed):
    ep = grip(seed, "paper-m2")
    assert ep.gripped and ep.final_offset_um <= 10.0
    assert ep.iterations >= 2 and len(ep.trajectory_mm) >= 2
    assert max(ep.location_error_px.values()) < 0.5


def test_cli_grip_prints_one_json_line_last():
    r = subprocess.run([sys.executable, "-m", "slmlab", "grip", "--seed", "3", "--model", "paper-m2", "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout.strip().splitlines()[-1])
    for key in ("tip_error_um", "target_error_um", "final_offset_um", "gripped", "iterations"):
        assert key in d
    assert isinstance(d["gripped"], bool)


def test_cli_grip_unknown_model_is_a_user_error():
    r = subprocess.run([sys.executable, "-m", "slmlab", "grip", "--model", "nope"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and r.stderr.count("\n") == 1
