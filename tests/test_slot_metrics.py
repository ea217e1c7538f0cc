import numpy as np
import pytest

from ocpipe.encoders import slot_metrics as SM


def test_ari_is_one_for_relabelled_partitions_and_near_zero_for_random():
    a = np.repeat([0, 1, 2], 50)
    # exact: a relabelling has the same row and column sums, so the ARI's numerator and denominator are one float
    assert SM.adjusted_rand_index(a, (a + 1) % 3 * 7) == 1.0
    rng = np.random.default_rng(0)
    # derived: sampling, not round-off: two independent 3-class labelings of 3000 points give an ARI of sd 5.2e-4
    # (300 seeds); 0.02 is over 30 sd, and a real match scores 1
    assert abs(SM.adjusted_rand_index(rng.integers(0, 3, 3000), rng.integers(0, 3, 3000))) < 0.02


def test_ari_against_a_hand_computed_case():
    # contingency [[2,1,0],[0,1,2]]: index 2, expected 6*3/15 = 1.2, max 0.5*(6+3) = 4.5 -> 0.8/3.3
    ari = SM.adjusted_rand_index(np.array([0, 0, 0, 1, 1, 1]), np.array([0, 0, 1, 1, 2, 2]))
    # derived: three float64 roundings on each side (<= 1e-15 relative); approx's 1e-6 default is far above that and
    # far below the step to another contingency's ARI
    assert ari == pytest.approx(0.8 / 3.3)


def _one_hot(pred, K):
    return np.moveaxis(np.eye(K)[pred], -1, 1)


def test_perfect_masks_score_perfectly():
    ids = np.zeros((2, 8, 8), int)
    ids[:, 2:4, 2:4] = 1
    ids[:, 5:8, :] = 2
    masks = _one_hot(ids, 4)
    scores = SM.decomposition_scores(masks, ids, ids > 0, {"cube": ids == 1})
    # exact: identical partitions give (x - e) / (x - e) = 1 per image, and the IoU 4 / 4
    assert scores["fg_ari_mean"] == 1.0 and scores["best_slot_iou_cube"] == 1.0


def test_merged_objects_lower_the_scores():
    ids = np.zeros((1, 8, 8), int)
    ids[:, 2:4, 2:4] = 1
    ids[:, 5:8, :] = 2
    pred = np.where(ids > 0, 1, 0)  # cube and robot share one slot
    scores = SM.decomposition_scores(_one_hot(pred, 3), ids, ids > 0, {"cube": ids == 1})
    # exact: integer pair counts (282 * 378 / 378 = 282 = the index), and 4 / 28 rounded once on both sides
    assert scores["fg_ari_mean"] == 0.0 and scores["best_slot_iou_cube"] == 4 / 28


def test_separation_counts_an_object_whose_slot_also_takes_background_as_separate():
    ids = np.zeros((2, 8, 8), int)
    ids[:, 2:4, 2:4] = 1  # cube
    ids[:, 5:8, :] = 2  # robot
    pred = np.where(ids == 2, 2, 0)
    pred[0][ids[0] == 1] = 1
    pred[0, 0, :] = 1  # image 0: the cube's slot also takes a row of background (IoU 4/12), still its own
    pred[1][ids[1] == 1] = 2  # image 1: cube and robot share a slot
    named = {"cube": ids == 1, "robot": ids == 2}
    s = SM.decomposition_scores(_one_hot(pred, 3), ids, ids > 0, named)
    # exact: means of one True and one False
    assert s["separate_cube_robot"] == 0.5
    assert s["own_slot_cube"] == 0.5 and s["own_slot_robot"] == 0.5
    # exact: the mean of two IoUs is their one rounded sum halved, the same operations in the same order as here
    assert s["best_slot_iou_cube"] == (4 / 12 + 4 / 28) / 2


def test_mask_diagnostics_on_disjoint_and_uniform_masks():
    disjoint = _one_hot(np.repeat(np.arange(4), 16).reshape(1, 8, 8), 4)
    d = SM.mask_diagnostics(disjoint)
    # derived: the entropy clips p at 1e-9, so each pixel's 3 empty slots add 1e-9 ln(1e9) nats each; a handful of
    # float64 operations and a mean of 64 equal terms (<= 1e-14 relative), far inside approx's 1e-6 default
    assert d["slot_overlap_mean"] == 0 and d["slot_entropy_per_pixel_nats"] == pytest.approx(3e-9 * np.log(1e9))
    assert d["slot_activation_mean"] == [0.25] * 4  # exact: 16 ones over 64 pixels
    uniform = np.full((1, 4, 8, 8), 0.25)
    u = SM.mask_diagnostics(uniform)
    # A_i.A_j / min(sum A_i, sum A_j) = 64/16 / 16 for four equal masks
    assert u["slot_overlap_mean"] == 0.25  # exact: sums of 1/16 and of 1/4 are exact in binary
    # derived: 4 terms -0.25 ln 0.25 summed, then a mean of 64 equal ones (<= 1e-14 relative); approx's 1e-6 default
    # is far above that and far below the entropy of any other mix of 4 slots
    assert u["slot_entropy_per_pixel_nats"] == pytest.approx(np.log(4))
    assert u["spatial_coherence_mean_abs_diff"] == 0


def test_temporal_diversity_is_mean_pairwise_distance_per_trajectory():
    tokens = np.array([[0.0], [3.0], [0.0], [0.0]])
    # trajectory 0: one pair at distance 3; trajectory 1: identical frames
    assert SM.temporal_diversity(tokens, np.array([0, 0, 1, 1])) == 1.5  # exact: sqrt(9) = 3 and 0, halved
