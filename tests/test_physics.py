"""The simulated skin's physics, pinned (docs/simulator.md)."""

import dataclasses

import numpy as np
import pytest

from eskin.device.physics import Indenter, SkinModel, SkinParams, Trial, spread_kernel

PARAMS = SkinParams()


@pytest.fixture(scope="module")
def skin():
    return SkinModel(PARAMS)


def test_noiseless_capacitance_is_linear_in_stretch(skin):
    stretches = np.linspace(1.0, 1.3, 13)
    caps = np.array([skin.capacitance(s) for s in stretches])
    for terminal in range(20):
        fit = np.polyfit(stretches, caps[:, terminal], 1)
        residual = caps[:, terminal] - np.polyval(fit, stretches)
        r2 = 1 - residual.var() / caps[:, terminal].var()
        assert r2 > 0.999
        assert fit[0] > 0


def test_force_response_is_monotone_and_saturating(skin):
    forces = np.linspace(0, 60, 121)
    response = np.array([skin.capacitance(1.0, [Indenter(5, 5, f)])[4] for f in forces])
    steps = np.diff(response)
    assert np.all(steps > 0), "more force must always read more"
    assert steps[-1] < steps[10] / 20, "the response must flatten out"
    ceiling = skin.capacitance(1.0, [Indenter(5, 5, 1e9)])[4]
    assert response[-1] < ceiling and ceiling < np.inf


def test_light_weights_read_less_repeatably_than_seated_heavy_ones():
    """Fig. 6 of the paper, from the seating mechanism: a light weight bears on a part of
    its footprint that varies with its tilt; a weight past its seating load on all of it."""
    tilted = SkinModel(dataclasses.replace(PARAMS, seating_force_n=3.0, seating_variation=0.5))
    rest = tilted.capacitance(1.0)[4]

    def relative_spread(newtons):
        change = np.array([tilted.capacitance(1.0, [Trial(tilted, [n]).place(5, 5, newtons)])[4]
                           for n in range(300)]) - rest
        return change.std() / change.mean()

    light, heavy = relative_spread(1.2936), relative_spread(5.2136)
    assert light > 0.2 and heavy < light / 2, (light, heavy)


def test_each_node_of_a_hand_made_skin_has_its_own_sensitivity():
    even = SkinModel(PARAMS)
    uneven = SkinModel(dataclasses.replace(PARAMS, node_sensitivity_spread=0.2))
    assert np.all(even.node_sensitivity == 1.0)
    spread = np.log(uneven.node_sensitivity).std()
    assert 0.15 < spread < 0.25
    # the same skin every time: drawn from the seed, not per trial
    assert np.array_equal(uneven.node_sensitivity,
                          SkinModel(dataclasses.replace(PARAMS, node_sensitivity_spread=0.2))
                          .node_sensitivity)


def test_stretch_stiffens_the_indentation_response(skin):
    strain = [skin.peak_strain(3.0, s) for s in (1.0, 1.07921, 1.15842)]
    assert strain[0] > strain[1] > strain[2] > 0


@pytest.mark.parametrize("x", [1, 5, 10])
def test_an_indentation_reaches_two_nodes_each_way_and_no_further(skin, x):
    rest = skin.capacitance(1.0)
    for offset in (-0.45, 0.0, 0.45):
        pressed = skin.capacitance(1.0, [Indenter(x, 6, 5.2136, (offset, offset))])
        changed = np.flatnonzero(~np.isclose(pressed[:10], rest[:10], rtol=0, atol=1e-12)) + 1
        reach = {n for n in range(1, 11) if abs(n - x) <= 2}
        assert set(changed) == reach, (offset, changed)
        changed_y = np.flatnonzero(~np.isclose(pressed[10:], rest[10:], rtol=0, atol=1e-12)) + 1
        assert set(changed_y) == {4, 5, 6, 7, 8}


def test_spread_kernel_is_one_at_the_centre_and_zero_from_reach_plus_half():
    assert spread_kernel(np.array([0.0]), 2)[0] == 1.0
    assert spread_kernel(np.array([2.5, 3.0]), 2).tolist() == [0.0, 0.0]
    assert 0 < spread_kernel(np.array([2.0]), 2)[0] < spread_kernel(np.array([1.0]), 2)[0] < 1


def test_reading_noise_matches_its_parameter():
    quiet = dataclasses.replace(PARAMS, drift_offset_pf=0.0, drift_step_pf=0.0, noise_pf=0.05)
    trial = Trial(SkinModel(quiet), [1])
    readings = trial.sample_pf(20_000, 1.0, [])
    clean = SkinModel(quiet).capacitance(1.0)
    noise = readings - clean
    assert np.allclose(noise.mean(axis=0), 0, atol=0.003)
    assert np.allclose(noise.std(axis=0), 0.05, rtol=0.05)


def test_drift_offset_and_random_walk_match_their_parameters():
    drifty = dataclasses.replace(PARAMS, noise_pf=0.0, drift_offset_pf=0.2, drift_step_pf=0.01)
    model = SkinModel(drifty)
    offsets = np.array([Trial(model, [n]).sample_pf(1, 1.0, [])[0] for n in range(2000)])
    start = offsets - model.capacitance(1.0)
    # first reading = offset + one walk step
    assert np.allclose(start.std(axis=0), np.hypot(0.2, 0.01), rtol=0.1)
    walk = Trial(model, [1]).sample_pf(5000, 1.0, [])
    assert np.allclose(np.diff(walk, axis=0).std(axis=0), 0.01, rtol=0.05)


def test_placement_errors_stay_within_their_bound_and_follow_their_sd():
    model = SkinModel(PARAMS)
    trial = Trial(model, [3])
    offsets = np.array([trial.place(5, 5, 1.0).offset for _ in range(5000)])
    assert np.abs(offsets).max() <= PARAMS.placement_max_nodes
    assert np.allclose(offsets.std(axis=0), PARAMS.placement_sd_nodes, rtol=0.1)


def test_trials_are_deterministic_and_distinct(skin):
    a = Trial(skin, [42]).sample_counts(20, 1.0, [])
    b = Trial(skin, [42]).sample_counts(20, 1.0, [])
    c = Trial(skin, [43]).sample_counts(20, 1.0, [])
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_adc_quantises_to_ten_bits_and_clips_at_the_rails(skin):
    counts = skin.to_counts(np.array([[0.0] * 20, [1e6] * 20, list(skin.baseline_pf)]))
    assert counts.dtype == np.int64
    assert counts[0].tolist() == [0] * 20 and counts[1].tolist() == [1023] * 20
    assert np.all((counts[2] > 100) & (counts[2] < 600)), "rest readings sit mid-range"


def test_unknown_or_invalid_parameters_are_rejected_by_name():
    with pytest.raises(ValueError, match="noise_sd"):
        SkinParams.from_mapping({"noise_sd": 1.0})
    with pytest.raises(ValueError, match="strain_max"):
        SkinParams.from_mapping({"strain_max": 1.5})


@pytest.mark.parametrize(("rows", "columns"), [(8, 8), (16, 12)])
def test_a_skin_of_any_size_has_its_own_terminals_and_nodes(rows, columns):
    from eskin.skin import Skin

    model = SkinModel(PARAMS, Skin(rows, columns))
    assert model.capacitance(1.0).shape == (rows + columns,)
    assert model.node_sensitivity.shape == (rows, columns)
    field = model.strain_field([Indenter(rows, 1, 5.0)], 1.0)
    assert field.shape == (rows, columns) and field[rows - 1, 0] == field.max() > 0
    assert Trial(model, [1]).sample_counts(4, 1.0, []).shape == (4, rows + columns)


def test_a_channel_array_is_not_simulated():
    from eskin.skin import ChannelArray

    with pytest.raises(ValueError, match="the simulated skin is a row/column skin; array of "
                       "3 channels, 2 × 2 press positions is recorded by another instrument"):
        SkinModel(PARAMS, ChannelArray(("a", "b", "c"), 2, 2))


def test_the_bayes_bound_reads_a_skin_of_any_size(repo_params):
    """harness.oracle on a 6 × 5 skin: the simulated board's readings of a weight on each
    corner, and of none, are placed where they were pressed."""
    import pandas as pd

    from eskin.device.board import SimulatedBoard
    from eskin.device.protocol import Frame, FrameParser
    from eskin.skin import Skin
    from harness import oracle

    sim, skin = SkinParams.from_mapping(repo_params["sim"]), Skin(6, 5)
    board, parser, rows = SimulatedBoard(sim, skin=skin), FrameParser(skin.terminals), []
    for trial, (x, y) in enumerate([(0, 0), (1, 1), (6, 5), (3, 2)], start=1):
        board.handle(b"SIM TRIAL %d" % trial)
        board.handle(b"SIM CLEAR")
        if x:
            board.handle(f"SIM PRESS {x} {y} 3.2536".encode())
        frames = [e for e in parser.feed(board.handle(b"SAMPLE 3")) if isinstance(e, Frame)]
        rows += [{**dict(zip(skin.channels, f.counts, strict=True)), "sample": i,
                  "stretch": 1.0, "force": 3.2536 if x else 0.0, "x": x, "y": y}
                 for i, f in enumerate(frames)]
    frame = pd.DataFrame(rows)
    answers = oracle.posterior_predictions(frame, sim, [1.0], [0.0, 3.2536], skin=skin)
    touching = frame["x"] > 0
    assert answers["contact"].tolist() == touching.tolist()
    assert (answers.loc[touching, ["x", "y"]].to_numpy()
            == frame.loc[touching, ["x", "y"]].to_numpy()).all()
