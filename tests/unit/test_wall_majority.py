"""The wall fit takes a plane only when a clear majority of the spots agrees on it (align.wall).

The spots of config/sim.toml around a 2 x 1.5 m opening; the true wall is z = 0 (normal +z into the
wall, the laser 350 mm in front). A spot that hit a rib, a seal or the opening reads off that plane.
"""

import numpy as np
import pytest

from cellctl.align import AlignmentError, fit_wall_plane

SPOTS_XY = np.array([[-1500, -60], [-500, -60], [60, 300], [60, 1200], [-1000, 1560], [-2060, 750]], float)


def _fit(P: np.ndarray):
    return fit_wall_plane(P, P - [0.0, 0.0, 350.0], inlier_threshold_mm=0.5, max_rms_mm=0.2)


def _wall(noise_mm: float = 0.005, seed: int = 0) -> np.ndarray:
    return np.column_stack([SPOTS_XY, np.random.default_rng(seed).normal(0.0, noise_mm, len(SPOTS_XY))])


def test_three_spots_on_a_trim_strip_beside_three_on_the_wall_are_refused():
    # Spots 0, 1 (the top) and 2 (the side) read a trim strip 4 mm proud: two groups of three, each a
    # perfect plane; before the majority rule the group with the lower spot numbers won.
    P = _wall()
    P[[0, 1, 2], 2] -= 4.0
    with pytest.raises(AlignmentError) as err:
        _fit(P)
    assert "spots off the wall" in str(err.value), err.value


def test_four_readings_with_one_bad_are_refused_not_fitted_through_the_bad_one():
    # Two spots gave no reading; of the four left, spot 0 is 3 mm off: any three make a perfect plane.
    P = _wall()[:4]
    P[0, 2] += 3.0
    with pytest.raises(AlignmentError, match="only 3 of 4 spots agree"):
        _fit(P)


def test_two_groups_of_four_on_different_planes_are_refused():
    # Seven spots: 0-3 on the wall; 3-6 on a surface through spot 3 tilted 0.5 deg about x (spot 3 lies on
    # both). Four of seven is a majority for either plane: the fit cannot tell the wall from the other.
    xy = np.array([[-1500, -60], [-500, -60], [60, 300], [60, 1200], [-1000, 1560], [-2060, 750], [-300, 500]], float)
    z = np.zeros(len(xy))
    z[4:] = np.tan(np.radians(0.5)) * (xy[4:, 1] - 1200.0)
    with pytest.raises(AlignmentError, match="two groups of 4 of 7 spots agree on different planes"):
        _fit(np.column_stack([xy, z]))


def test_one_spot_off_the_wall_is_rejected_and_the_true_plane_kept():
    P = _wall()
    P[2, 2] += 3.0
    w = _fit(P)
    assert w.inliers == (0, 1, 3, 4, 5) and [r.index for r in w.rejected] == [2]
    assert abs(w.offset) < 0.02 and np.degrees(np.arccos(min(1.0, w.normal[2]))) < 0.002


def test_the_sweeps_many_readings_with_a_few_off_the_wall_keep_the_true_plane():
    rng = np.random.default_rng(3)
    xy = np.column_stack([rng.uniform(-2060, 60, 400), rng.uniform(-60, 1560, 400)])
    P = np.column_stack([xy, rng.normal(0.0, 0.005, 400)])
    P[:40, 2] += rng.uniform(2.0, 10.0, 40)  # a tenth on a seal
    w = _fit(P)
    assert len(w.inliers) == 360 and abs(w.offset) < 0.01
