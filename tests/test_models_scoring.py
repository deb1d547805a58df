"""Scoring a scan against the phantom's truth (models/scoring.py): matching, false positives, cell statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.phantom import parse_phantom
from models.scoring import Detection, MapGrid, disc_iou, score_scan

PHANTOM = parse_phantom({
    "size_mm": [40, 40], "thickness_mm": 10, "youngs_modulus_kpa": 20.0,
    "inclusions": [
        {"center_mm": [10, 10], "radius_mm": 4, "depth_mm": 2, "youngs_modulus_kpa": 80.0},
        {"center_mm": [30, 30], "radius_mm": 3, "depth_mm": 2, "youngs_modulus_kpa": 40.0},
    ],
})


def grid(cell: float = 1.0) -> MapGrid:
    x = np.arange(cell / 2, 40, cell)
    s = np.full((x.size, x.size), 20.0)
    return MapGrid(s, x, x.copy(), np.ones(s.shape, dtype=np.int64))


def test_perfect_detection_scores_perfectly() -> None:
    found = [{"x_mm": 10.0, "y_mm": 10.0, "radius_mm": 4.0, "contrast": 3.0},
             {"x_mm": 30.0, "y_mm": 30.0, "radius_mm": 3.0, "contrast": 1.5}]
    s = score_scan(PHANTOM, found, grid())
    assert [i.found for i in s.inclusions] == [True, True]
    assert [i.centroid_error_mm for i in s.inclusions] == [0.0, 0.0]
    assert [i.ratio for i in s.inclusions] == [4.0, 2.0]
    assert s.false_positives == ()
    assert s.sensitivity == 1.0 and s.specificity == 1.0 and s.iou == 1.0 and s.symmetric_difference_mm2 == 0.0


def test_offset_detection_counts_cells_exactly() -> None:
    """A detection shifted by 1 mm along x on a 1 mm grid: one column of each side differs."""
    s = score_scan(PHANTOM, [Detection(11.0, 10.0, 4.0)], grid())
    first, second = s.inclusions
    assert first.found and first.centroid_error_mm == pytest.approx(1.0) and first.radius_error_mm == 0.0
    assert first.disc_iou == pytest.approx(disc_iou((10, 10), 4, (11, 10), 4))
    assert not second.found and math.isnan(second.centroid_error_mm)
    xx, yy = np.meshgrid(np.arange(0.5, 40), np.arange(0.5, 40))
    truth = ((xx - 10) ** 2 + (yy - 10) ** 2 <= 16) | ((xx - 30) ** 2 + (yy - 30) ** 2 <= 9)
    called = (xx - 11) ** 2 + (yy - 10) ** 2 <= 16
    assert s.true_positive_cells == int((truth & called).sum())
    assert s.false_positive_cells == int((~truth & called).sum())
    assert s.false_negative_cells == int((truth & ~called).sum())
    assert s.true_negative_cells == 1600 - int((truth | called).sum())
    assert s.sensitivity == pytest.approx((truth & called).sum() / truth.sum())


def test_far_detection_is_a_false_positive_and_matching_is_one_to_one() -> None:
    """Two detections on one inclusion: the nearer matches, the other is a false positive; one beyond R + tol
    matches nothing."""
    found = [Detection(10.4, 10.0, 3.0), Detection(8.0, 10.0, 3.0), Detection(30.0, 34.0, 1.0)]
    s = score_scan(PHANTOM, found, grid(2.0))  # tolerance = half a 2 mm cell: 3 + 1 = 4 mm, so 4.0 away does match
    assert s.inclusions[0].detection == found[0] and s.inclusions[0].radius_error_mm == -1.0
    assert s.inclusions[1].found and s.inclusions[1].centroid_error_mm == pytest.approx(4.0)
    assert s.false_positives == (found[1],)
    s = score_scan(PHANTOM, found, grid(2.0), tolerance_mm=0.5)
    assert not s.inclusions[1].found and set(s.false_positives) == {found[1], found[2]}


def test_no_detection_on_a_phantom_with_inclusions() -> None:
    s = score_scan(PHANTOM, [], grid())
    assert s.found == 0 and s.sensitivity == 0.0 and s.specificity == 1.0 and s.iou == 0.0
    assert "MISSED" in s.summary()[0]


def test_disc_iou_closed_forms() -> None:
    assert disc_iou((0, 0), 2, (0, 0), 2) == 1.0
    assert disc_iou((0, 0), 2, (5, 0), 2) == 0.0
    assert disc_iou((0, 0), 1, (0.5, 0), 2) == pytest.approx(0.25)  # contained: area ratio
    # two discs of radius 2 one radius apart: lens area 4 (2π/3 - √3/2)
    lens = 4 * (2 * math.pi / 3 - math.sqrt(3) / 2)
    assert disc_iou((0, 0), 2, (2, 0), 2) == pytest.approx(lens / (8 * math.pi - lens))


def test_bad_records_name_the_key() -> None:
    with pytest.raises(ValueError, match=r"inclusions\[0\]: y_mm must be a finite number"):
        score_scan(PHANTOM, [{"x_mm": 1.0, "y_mm": "a", "radius_mm": 1.0}], grid())
    with pytest.raises(ValueError, match="missing array 'count'"):
        score_scan(PHANTOM, [], {"stiffness": np.zeros((2, 2)), "x_mm": [0, 1], "y_mm": [0, 1]})


def test_scan_report_scores_a_run_against_its_phantom(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    import json

    import yaml

    from tools.scan_report import main

    g = grid()
    (tmp_path / "map").mkdir()
    np.savez(tmp_path / "map" / "map.npz", stiffness=g.stiffness, x_mm=g.x_mm, y_mm=g.y_mm, count=g.count)
    (tmp_path / "map" / "inclusions.json").write_text(json.dumps(
        [{"x_mm": 10.5, "y_mm": 10.0, "radius_mm": 4.0, "contrast": 3.0},
         {"x_mm": 25.0, "y_mm": 5.0, "radius_mm": 2.0, "contrast": 1.4}]))
    ph = tmp_path / "ph.yaml"
    ph.write_text(yaml.safe_dump({
        "size_mm": [40, 40], "thickness_mm": 10, "youngs_modulus_kpa": 20.0,
        "inclusions": [{"center_mm": [10, 10], "radius_mm": 4, "depth_mm": 2, "youngs_modulus_kpa": 80.0}]}))
    assert main([str(tmp_path), "--phantom", str(ph)]) == 0
    out = capsys.readouterr().out
    assert "1 of 1 found, 1 false positive(s)" in out
    assert "centroid error 0.50 mm" in out and "false positive at (25.0, 5.0)" in out


def test_scan_report_redetects_with_the_map_detector(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """``--redetect`` runs models.detector on map.npz (a map whose inclusions.json says nothing) and lists each
    detection's SNR."""
    import yaml

    from tools.scan_report import main

    rng = np.random.default_rng(1)
    xs = np.arange(20) * 2.0 + 1.0
    gy, gx = np.meshgrid(xs, xs, indexing="ij")
    stiff = 20.0 * np.exp(0.03 * rng.standard_normal(gx.shape)) * np.where(np.hypot(gx - 10, gy - 10) <= 4, 3.0, 1.0)
    (tmp_path / "map").mkdir()
    np.savez(tmp_path / "map" / "map.npz", stiffness=stiff, x_mm=xs, y_mm=xs, count=np.ones(gx.shape, dtype=int))
    (tmp_path / "map" / "inclusions.json").write_text("[]")
    ph = tmp_path / "ph.yaml"
    ph.write_text(yaml.safe_dump({
        "size_mm": [40, 40], "thickness_mm": 10, "youngs_modulus_kpa": 20.0,
        "inclusions": [{"center_mm": [10, 10], "radius_mm": 4, "depth_mm": 2, "youngs_modulus_kpa": 60.0}]}))
    assert main([str(tmp_path), "--phantom", str(ph)]) == 0
    assert "0 inclusion(s) found" in capsys.readouterr().out
    assert main([str(tmp_path), "--redetect", "--phantom", str(ph)]) == 0
    out = capsys.readouterr().out
    assert "1 inclusion(s) found" in out and "SNR" in out and "1 of 1 found, 0 false positive(s)" in out
    # a partial map (its node said so in map.npz) is reported, but the report fails and says why
    np.savez(tmp_path / "map" / "map.npz", stiffness=stiff, x_mm=xs, y_mm=xs, count=np.ones(gx.shape, dtype=int),
             incomplete=np.array("the scan did not finish"))
    assert main([str(tmp_path), "--redetect", "--phantom", str(ph)]) == 1
    assert "the map is INCOMPLETE: the scan did not finish" in capsys.readouterr().err
    # the map's probe picks the false-alarm law: a map of the camera probe's (its unit; or map.npz's model) is
    # thresholded with the camera's, as the map aggregator detected it
    from dataclasses import replace

    from models.detector import DetectorConfig, detect, false_alarm_law
    from nodes.mapping.map_output import read_map

    thresholds = {}
    for unit, model in (("kPa", "airfloat"), ("N/mm", "multi_indenter")):
        np.savez(tmp_path / "map" / "map.npz", stiffness=stiff, x_mm=xs, y_mm=xs, count=np.ones(gx.shape, dtype=int),
                 unit=np.array(unit))
        assert main([str(tmp_path), "--redetect"]) == 0
        first = capsys.readouterr().out.splitlines()[0]
        assert first.startswith(f"redetected on map.npz by the whole-map detector ({model} probe's false-alarm law): "
                                f"threshold "), first
        thresholds[model] = first.split("threshold ")[1].split(" ")[0]
        law = replace(DetectorConfig(), gumbel=false_alarm_law(model) or DetectorConfig().gumbel)
        assert thresholds[model] == f"{detect(read_map(tmp_path / 'map' / 'map.npz'), law).threshold_snr:.2f}"
    assert thresholds["airfloat"] != thresholds["multi_indenter"]


def test_redraw_misses_counts_a_coin_flip_inclusion_lost_to_its_own_redraw() -> None:
    from models.scoring import redraw_misses

    # found in every draw or in none: a redraw loses nothing
    assert redraw_misses([3, 0, 3], 3) == 0.0
    # found in 1 draw of 3: that run, redrawn, misses it with probability 1 (both other draws miss it)
    assert redraw_misses([1], 3) == pytest.approx(1.0)
    # found in 2 of 3: each of those two runs misses it in one of its two other draws: 2 x 1/2
    assert redraw_misses([2], 3) == pytest.approx(1.0)
    # two draws, found in one: that run's redraw is the other draw, which missed it
    assert redraw_misses([1, 2, 1], 2) == pytest.approx(2.0)
    assert redraw_misses([2, 3], 4) == pytest.approx((2 * 2 + 3 * 1) / 3)
    with pytest.raises(ValueError, match="at least 2"):
        redraw_misses([1], 1)
    with pytest.raises(ValueError, match=r"0\.\.3"):
        redraw_misses([4], 3)
