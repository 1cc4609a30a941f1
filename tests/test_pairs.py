"""Order-free scoring of two contacts, pinned on hand-made cases."""

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st

from eskin.evaluation.pairs import match_contacts, pair_outcomes, pair_scores, score_pairs
from eskin.skin import PAPER_SKIN


def sample(true, predicted, forces_true=(1.0, 5.0), forces_pred=(1.0, 5.0)):
    """One row: true and predicted contacts as ((x1, y1), (x2, y2))."""
    row = {}
    for i, (t, p) in enumerate(zip(true, predicted, strict=True), start=1):
        row.update({f"x{i}_true": t[0], f"y{i}_true": t[1], f"x{i}_pred": p[0],
                    f"y{i}_pred": p[1], f"force{i}_true": forces_true[i - 1],
                    f"force{i}_pred": forces_pred[i - 1]})
    return row


def outcomes(*rows):
    return pair_outcomes(pd.DataFrame(list(rows)))


def test_swapped_contacts_score_perfectly_when_matched_and_not_in_order():
    swapped = outcomes(sample(((1, 1), (6, 10)), ((6, 10), (1, 1)), forces_pred=(5.0, 1.0)))
    scores = pair_scores(swapped)
    assert scores["pair_accuracy"] == 1.0 and scores["contact_accuracy"] == 1.0
    assert scores["pair_accuracy_ordered"] == 0.0 and scores["contact_accuracy_ordered"] == 0.0
    assert scores["force_mae"] == 0.0  # each force follows its contact through the swap


def test_a_wrong_contact_costs_exactly_one():
    one_wrong = outcomes(sample(((1, 1), (6, 10)), ((1, 1), (6, 6))),
                         sample(((1, 1), (6, 10)), ((6, 6), (1, 1))))  # wrong and swapped
    assert one_wrong["wrong_contacts"].tolist() == [1, 1]
    assert one_wrong["wrong_contacts_ordered"].tolist() == [1, 2]
    scores = pair_scores(one_wrong)
    assert scores["pair_accuracy"] == 0.0
    assert scores["contact_accuracy"] == 0.5


def test_both_wrong_costs_two_and_ties_break_by_distance():
    row = sample(((1, 1), (10, 10)), ((9, 10), (2, 1)), forces_pred=(4.0, 2.0))
    result = outcomes(row)
    assert result["wrong_contacts"].item() == 2
    # (9, 10) is nearer (10, 10): the second true contact takes the first prediction.
    assert result["force2_matched"].item() == 4.0 and result["force1_matched"].item() == 2.0


def test_matching_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match=r"expected two \(n, k, 2\) arrays"):
        match_contacts(np.zeros((3, 2, 2)), np.zeros((3, 3, 2)))


nodes = st.tuples(st.integers(1, 10), st.integers(1, 10))


@given(st.lists(st.tuples(nodes, nodes, nodes, nodes), min_size=1, max_size=20))
def test_matching_never_scores_worse_than_the_order_given(cases):
    rows = [sample((a, b), (c, d)) for a, b, c, d in cases]
    result = outcomes(*rows)
    assert (result["wrong_contacts"] <= result["wrong_contacts_ordered"]).all()
    assert result["wrong_contacts"].between(0, 2).all()


def test_score_pairs_joins_localise_and_force_per_scheme_and_fold():
    rows = []
    for scheme in ("stratified", "conditions"):
        for trial in range(4):
            rows.append({"scheme": scheme, "trial": f"t{trial}", "sample": 0, "fold": trial % 2,
                         **sample(((1, 1), (6, 6)), ((6, 6), (1, 1)) if trial else ((1, 1), (1, 6)),
                                  forces_pred=(5.0, 1.0) if trial else (1.0, 5.0))})
    frame = pd.DataFrame(rows)
    loc = frame.drop(columns=[c for c in frame if c.startswith("force")])
    force = frame[["scheme", "trial", "sample", "force1_true", "force1_pred", "force2_true",
                   "force2_pred"]]
    scores = score_pairs(loc, force)
    assert set(scores) == {"stratified", "conditions"}
    # fold 0: trials 0 (one wrong) and 2 (swapped, right); fold 1: both right.
    assert scores["conditions"]["pair_accuracy"] == pytest.approx(0.75)
    assert scores["conditions"]["pair_accuracy_ordered"] == pytest.approx(0.0)
    with pytest.raises(ValueError, match="do not cover the same samples"):
        score_pairs(loc, force.iloc[:3])


def test_a_ghost_pair_is_counted_as_a_ghost_and_a_plain_error_is_not():
    truth = ((1, 1), (6, 10))
    ghost = outcomes(sample(truth, ((1, 10), (6, 1))))       # same rows and columns, re-paired
    other = outcomes(sample(truth, ((1, 1), (6, 6))))        # one contact wrong
    same_row = outcomes(sample(((1, 1), (1, 10)), ((1, 10), (1, 1))))  # no ghost exists
    assert ghost["ghost"].all() and pair_scores(ghost)["ghost_share"] == 1.0
    assert pair_scores(ghost)["pair_accuracy"] == 0.0
    assert not other["ghost"].any() and pair_scores(other)["ghost_share"] == 0.0
    assert not same_row["has_ghost"].any()


def test_active_terminals_find_the_pressed_rows_and_columns_in_any_units(repo_params):
    from eskin.data.plan import two_force_plan
    from eskin.device.physics import SkinParams
    from eskin.learning.estimators import ActiveTerminals
    from harness.calibrate import simulate_plan

    sim = SkinParams.from_mapping(repo_params["sim"])
    frame = simulate_plan(sim, two_force_plan("t", [1.0], [1.2936, 5.2136], [1, 6, 10],
                                              [1, 6, 10], samples=2), seed=3)
    X = frame[PAPER_SKIN.channels]  # by name: the x and y terminals
    features = ActiveTerminals().fit_transform(X)
    peaks_x = features[:, 20:22]                      # the two x peaks, lower first
    distinct = (frame["x1"] != frame["x2"]).to_numpy()
    truth = np.sort(frame[["x1", "x2"]].to_numpy(), axis=1) - 1
    assert np.mean(np.all(peaks_x[distinct] == truth[distinct], axis=1)) > 0.9
    in_farads = ActiveTerminals().fit_transform(X * 1e-12)
    assert np.allclose(in_farads, features, atol=1e-6)
