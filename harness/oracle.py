"""The Bayes bound: the best any model could do on data from the simulated skin.

An oracle that knows the simulator (:mod:`eskin.device.physics`) and the
plan's discrete conditions computes, for every single-force sample, the
posterior over conditions (stretch, force, node) from that one reading:

* the reading's mean given a condition depends on per-trial latents the
  oracle cannot see — the indenter's placement offset (x and y) and its
  seating (the load that seats it fully) — which are integrated out: a
  coarse grid drops, per sample, the conditions whose posterior is below
  e^-25 of the best one's; a fine grid shared by all samples integrates the
  rest and finds where each one's likelihood lives; each sample's leading
  conditions are integrated again on a grid around that place. The bound
  stage doubles every grid on a sample of rows and reports what moved (a
  converged bound moves no score by 0.001); where a score moved, it integrates
  on the doubled grid instead, and checks that, up to twice;
* given the mean, a reading (in pF) is Gaussian per channel: white noise,
  the baseline's drift (stationary in board time, so the same variance at every
  sample), and the ADC's quantisation step (as uniform noise). Creep is left out:
  an acquisition reads its weights from the moment they land, and over a 20-frame
  trial creep moves the strain by about 0.1 % (docs/simulator.md);
* the prior is the plan's: each condition's share of the samples.

The skin is the scene's (any row/column skin: ``skin``, the paper's by default), read
through the same :class:`~eskin.device.physics.SkinModel` as the simulator built.

Its decisions are Bayes-optimal for each metric — the posterior mean for
stretch and force (least squares), the most probable answer for contact and
for x and y of a contact — so its scores bound what a model predicting one
sample at a time can reach. Under stratified CV a model sees the other
samples of the same trial and may beat it; under conditions CV it cannot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.special import logsumexp, ndtr

from eskin.data.schema import contact_mask
from eskin.device.physics import SkinModel, SkinParams, spread_kernel
from eskin.kinds import ONE_CONTACT
from eskin.skin import PAPER_SKIN, AnySkin


@dataclass(frozen=True)
class Conditions:
    """The plan's conditions: labels and prior."""

    log_prior: np.ndarray    # (conditions,)
    stretch: np.ndarray      # (conditions,)
    force: np.ndarray        # physical force, 0 when contact-free
    x: np.ndarray            # 0 when contact-free
    y: np.ndarray


def _normal_grid(points: int, sd: float, limit: float = 6.0) -> tuple[np.ndarray, np.ndarray]:
    """Latent values and weights (summing to 1) for E[f(Z)], Z ~ N(0, sd²) clipped to ±limit·sd.

    An even grid with the normal density as weights, and the tails' mass on the end
    points (as the simulator clips): unlike Gauss–Hermite, it does not miss a narrow
    likelihood between its nodes, and it converges as the grid is refined."""
    if sd == 0 or points == 1:
        return np.zeros(1), np.ones(1)
    z = np.linspace(-limit, limit, points)
    step = z[1] - z[0]
    edges = np.concatenate([[-np.inf], z[:-1] + step / 2, [np.inf]])
    weights = np.diff(ndtr(edges))  # each point's cell, tails in the end cells
    return z * sd, weights / weights.sum()


@dataclass(frozen=True)
class Grid:
    """How finely the latents are integrated: points per offset axis and for the seating on
    the grid every condition shares, and cells per axis of each sample's own box."""

    offset_points: int = 5
    seating_points: int = 81
    local_cells: int = 12

    def doubled(self) -> Grid:
        return Grid(2 * self.offset_points - 1, 2 * self.seating_points - 1,
                    2 * self.local_cells)


# The shared grids rank conditions and find, per sample and condition, where its likelihood
# lives. Light weights read through their seating, and with little noise its likelihood is
# narrow (about 0.1 SD of the seating wide: FINE's seating step is 0.11 SD); heavy weights
# pin the placement offset down to about 0.2 SD, far below FINE's offset step (1.5 SD). So
# each sample's leading conditions (within e^-REFINE_LOG of its best: FINE's coarse offsets
# can misjudge a heavy weight's condition by several log units, and `convergence` shows
# that the margin suffices) are integrated again on their own box: the FINE
# points within e^-BOX_LOG of the best, one step more each side, cut in `local_cells` even
# cells per offset axis (0.25 SD where the box is narrowest) and at least FINE's step for
# the seating. `convergence` measures, per run, what doubling every grid moves. The coarse
# pass only ranks conditions; a half-step miss costs it a few log units, far within
# PRUNE_LOG.
COARSE = Grid(3, 25)
FINE = Grid()
PRUNE_LOG = 25.0  # conditions this far (in log posterior) below a sample's best are dropped
REFINE_LOG = 12.0  # conditions this close to a sample's best are integrated on their boxes
BOX_LOG = 20.0    # a sample's box holds the FINE points this close to its best
SEATING_LIMIT = 4.5  # SDs: the seatings beyond carry 7e-6 of the mass


def _box_rule(z: np.ndarray, lo: int, hi: int, cells: int, sd: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Latent values and their probability masses over grid points z[lo]..z[hi] (in SDs):
    ``cells`` even cells at their midpoints, plus, where the box reaches the grid's end, the
    mass beyond it on the end point (the simulator clips there)."""
    if len(z) == 1:
        return np.zeros(1), np.ones(1)
    edges = np.linspace(z[lo], z[hi], cells + 1)
    values = [(edges[:-1] + edges[1:]) / 2]
    masses = [np.diff(ndtr(edges))]
    if lo == 0:
        values.insert(0, z[:1])
        masses.insert(0, ndtr(z[:1]))
    if hi == len(z) - 1:
        values.append(z[-1:])
        masses.append(ndtr(-z[-1:]))
    return np.concatenate(values) * sd, np.concatenate(masses)


def _pressed_means(model: SkinModel, stretch: float, newtons: float, x: int, ys: np.ndarray,
                   offsets_x: np.ndarray, offsets_y: np.ndarray, seatings: np.ndarray
                   ) -> np.ndarray:
    """Mean readings of a weight on (x, y) for each y of ``ys`` and every combination of the
    latents: (len(ys), offsets_x × offsets_y × seatings, terminals), latents in that
    order."""
    p = model.params
    stretched = model.baseline_pf * (1 + model.stretch_sensitivity * (stretch - 1))
    peaks = np.array([model.peak_strain(newtons, stretch, s) for s in seatings])
    wx = spread_kernel(model.x_nodes[None, :] - (x + offsets_x[:, None]),
                       p.reach_nodes)  # (ox, rows)
    wy = spread_kernel(model.y_nodes[None, None, :] - (np.asarray(ys, dtype=float)[:, None, None]
                                               + offsets_y[None, :, None]), p.reach_nodes)
    field = (wx[None, :, None, None, :, None] * wy[:, None, :, None, None, :]
             * peaks[None, None, None, :, None, None])
    # axes: (y, ox, oy, seating, i, j) → strain at node (i, j)
    field = np.minimum(field * model.node_sensitivity, p.strain_max)
    gain = 1.0 / (1.0 - field) - 1.0
    indentation = np.concatenate([gain.mean(axis=5), gain.mean(axis=4)], axis=-1)
    return (stretched * (1 + indentation)).reshape(len(ys), -1, model.skin.terminals)


class _Latents:
    """The latent grid of one :class:`Grid` and the mean readings it gives, per condition,
    computed when first asked for (a fine grid over every condition would not fit)."""

    def __init__(self, model: SkinModel, grid: Grid) -> None:
        p = model.params
        self.model, self.grid = model, grid
        limit = p.placement_max_nodes / p.placement_sd_nodes if p.placement_sd_nodes else 0.0
        offsets, offset_w = _normal_grid(grid.offset_points, p.placement_sd_nodes, limit)
        seatings, seating_w = _normal_grid(grid.seating_points, p.seating_variation,
                                           SEATING_LIMIT)
        self.offsets, self.seatings = offsets, np.exp(seatings)
        # Each axis in SDs and its SD: (offset x, offset y, seating)
        self.axes = [(offsets / p.placement_sd_nodes if p.placement_sd_nodes else offsets,
                      p.placement_sd_nodes)] * 2 + [
            (seatings / p.seating_variation if p.seating_variation else seatings,
             p.seating_variation)]
        self.shape = (len(offsets), len(offsets), len(seatings))
        self.n = int(np.prod(self.shape))
        self.log_weights = np.log(np.einsum("i,j,k->ijk", offset_w, offset_w, seating_w).ravel())
        self._cache: dict[tuple[float, float, int], np.ndarray] = {}

    def free(self, stretch: float) -> np.ndarray:
        """Contact-free: one mean, whatever the latents."""
        m = self.model
        stretched = m.baseline_pf * (1 + m.stretch_sensitivity * (stretch - 1))
        return np.broadcast_to(stretched, (self.n, m.skin.terminals))

    def pressed(self, stretch: float, newtons: float, x: int) -> np.ndarray:
        """Means of a weight on (x, y) for every y: (columns, latents, terminals) in (ox, oy,
        seating) order."""
        key = (stretch, newtons, x)
        if key not in self._cache:
            self._cache[key] = _pressed_means(self.model, stretch, newtons, x, self.model.y_nodes,
                                              self.offsets, self.offsets, self.seatings)
        return self._cache[key]

    def means(self, conditions: Conditions, which: np.ndarray) -> np.ndarray:
        """(len(which), latents, terminals)."""
        return np.stack([
            self.free(conditions.stretch[i]) if conditions.x[i] == 0 else
            self.pressed(conditions.stretch[i], conditions.force[i], conditions.x[i])[
                conditions.y[i] - 1]
            for i in which])

    def refined(self, conditions: Conditions, i: int, reading: np.ndarray,
                inverse_variance: np.ndarray) -> float:
        """log p(reading | pressed condition i), integrated on the reading's own box."""
        stretch, newtons, x = conditions.stretch[i], conditions.force[i], conditions.x[i]
        y = conditions.y[i]
        means = self.pressed(stretch, newtons, x)[y - 1]
        loglik = (-0.5 * (((reading - means) ** 2) @ inverse_variance)
                  + self.log_weights).reshape(self.shape)
        near = loglik >= loglik.max() - BOX_LOG
        rules = []
        for axis, ((z, sd), points) in enumerate(zip(self.axes, self.shape, strict=True)):
            held = np.flatnonzero(near.any(axis=tuple(a for a in range(3) if a != axis)))
            lo, hi = max(held[0] - 1, 0), min(held[-1] + 1, points - 1)
            cells = self.grid.local_cells if axis < 2 else max(self.grid.local_cells, hi - lo)
            rules.append(_box_rule(z, lo, hi, cells, sd))
        (ox, wx), (oy, wy), (seating, ws) = rules
        local = _pressed_means(self.model, stretch, newtons, x, np.array([y]), ox, oy,
                               np.exp(seating))[0]
        log_weights = np.log(np.einsum("i,j,k->ijk", wx, wy, ws).ravel())
        return float(logsumexp(-0.5 * (((reading - local) ** 2) @ inverse_variance)
                               + log_weights))


def plan_conditions(params: SkinParams, stretches, forces,
                    skin: AnySkin = PAPER_SKIN) -> Conditions:
    """The conditions of a single-force plan on ``skin`` (docs/scenes.md): labels and
    prior."""
    labels = []
    for stretch in np.asarray(stretches, dtype=float):
        labels.append((stretch, 0.0, 0, 0, "free"))
        for newtons in (float(f) for f in forces if f > 0):
            labels += [(stretch, newtons, x, y, "contact")
                       for x, y in skin.nodes()]
    stretch_l, force_l, x_l, y_l, kind = zip(*labels, strict=True)
    kind = np.array(kind)
    # The plan records every node at 0 N and node 0 at every force as contact-free
    # (docs/scenes.md, label convention): per stretch, nodes × 1 + 1 × forces such rows.
    free_share = skin.n_nodes + len(forces)
    prior = np.where(kind == "free", float(free_share), 1.0)
    return Conditions(log_prior=np.log(prior / prior.sum()), stretch=np.array(stretch_l),
                      force=np.array(force_l), x=np.array(x_l), y=np.array(y_l))


def counts_to_pf(model: SkinModel, counts: np.ndarray) -> np.ndarray:
    """Invert the read-out (CAV424 + ADC) to capacitance in pF."""
    p = model.params
    volts = counts / (2**p.adc_bits - 1) * p.supply_v
    return p.cav424_ref_pf * (1 + (volts - p.cav424_offset_v) / model.cav424_gain_v)


def reading_variance(model: SkinModel, sample_index: np.ndarray) -> np.ndarray:
    """Per-sample, per-channel variance of a reading about its mean, in pF² (the same at
    every sample index: the drift is stationary)."""
    p = model.params
    step_pf = p.cav424_ref_pf * (p.supply_v / (2**p.adc_bits - 1)) / model.cav424_gain_v
    every = np.zeros((len(np.asarray(sample_index)), 1))
    return every + p.noise_pf**2 + p.drift_offset_pf**2 + step_pf[None, :] ** 2 / 12


def _log_marginal(readings: np.ndarray, inverse_variance: np.ndarray, means: np.ndarray,
                  log_weights: np.ndarray, block_values: int = 8_000_000) -> np.ndarray:
    """log p(reading | condition) for rows × conditions, the latents integrated out.

    ``means`` is (conditions, latents, terminals). Σ_i (r_i − μ_i)² / v_i with per-row v:
    the square expanded into three products, so that the big one is a matrix product;
    conditions go in blocks of about ``block_values`` likelihoods, a bounded buffer."""
    n_cond, n_lat, terminals = means.shape
    out = np.empty((len(readings), n_cond))
    step = max(1, block_values // max(1, len(readings) * n_lat))
    weighted = readings * inverse_variance
    squares = (readings * weighted).sum(1)[:, None]
    for start in range(0, n_cond, step):
        flat = means[start:start + step].reshape(-1, terminals).T
        quad = squares - 2.0 * weighted @ flat + inverse_variance @ (flat * flat)
        loglik = -0.5 * quad.reshape(len(readings), -1, n_lat)
        out[:, start:start + step] = logsumexp(loglik + log_weights, axis=2)
    return out


def posterior_predictions(frame: pd.DataFrame, params: SkinParams, stretches, forces, *,
                          skin: AnySkin = PAPER_SKIN, grid: Grid = FINE, chunk: int = 96,
                          progress=None) -> pd.DataFrame:
    """The oracle's answers for each row of a scene on ``skin``: stretch, force, contact (+
    probability), x, y."""
    model = SkinModel(params, skin)
    cond = plan_conditions(params, stretches, forces, skin)
    every = np.arange(len(cond.x))
    coarse, fine = _Latents(model, COARSE), _Latents(model, grid)
    coarse_means = coarse.means(cond, every)
    readings = counts_to_pf(model, frame[skin.channels].to_numpy(dtype=float))
    inverse = 1.0 / reading_variance(model, frame["sample"].to_numpy())
    contact = cond.x > 0
    x_onehot = (cond.x[:, None] == model.x_nodes[None, :].astype(int)) & contact[:, None]
    y_onehot = (cond.y[:, None] == model.y_nodes[None, :].astype(int)) & contact[:, None]
    # The coarse pass ranks the conditions of every row; rows it finds alike share their
    # candidates, so the fine pass takes them in chunks of alike rows.
    coarse_post = np.concatenate([
        _log_marginal(readings[i:i + chunk], inverse[i:i + chunk], coarse_means,
                      coarse.log_weights) + cond.log_prior
        for i in range(0, len(frame), chunk)]) if len(frame) else np.empty((0, len(every)))
    order = np.argsort(np.argmax(coarse_post, axis=1), kind="stable")
    log_post = np.full(coarse_post.shape, -np.inf)
    for start in range(0, len(frame), chunk):
        rows = order[start:start + chunk]
        near = coarse_post[rows] >= coarse_post[rows].max(axis=1, keepdims=True) - PRUNE_LOG
        candidates = np.flatnonzero(near.any(axis=0))
        log_post[np.ix_(rows, candidates)] = _log_marginal(
            readings[rows], inverse[rows], fine.means(cond, candidates),
            fine.log_weights) + cond.log_prior[candidates]
    # Each sample's surviving pressed conditions again, on their own boxes.
    for done, row in enumerate(range(len(frame)), start=1):
        near = np.flatnonzero((log_post[row] >= log_post[row].max() - REFINE_LOG) & contact)
        for i in near:
            log_post[row, i] = (fine.refined(cond, i, readings[row], inverse[row])
                                + cond.log_prior[i])
        if progress is not None and (done % chunk == 0 or done == len(frame)):
            progress(done, len(frame))
    log_post -= logsumexp(log_post, axis=1, keepdims=True)
    post = np.exp(log_post)
    out = {"stretch": post @ cond.stretch, "force": post @ cond.force,
           # sums of exps: 1 + 1e-16 happens
           "contact_probability": np.clip(post @ contact, 0.0, 1.0),
           # Localisation is asked of contacts only: the node posterior given contact.
           "x": np.argmax(post @ x_onehot, axis=1) + 1,
           "y": np.argmax(post @ y_onehot, axis=1) + 1}
    result = pd.DataFrame(out)
    result["contact"] = result["contact_probability"] > 0.5
    return result


CONVERGED = 1e-3  # largest move of any score, when the grid is doubled, of a converged bound


def mse_over_variance(truth, predicted) -> float:
    """The mean squared error over the target's variance, so that a move reads as a move in
    R² (the MSE itself where the target is constant)."""
    truth = np.asarray(truth, dtype=float)
    error = float(np.mean((truth - np.asarray(predicted, dtype=float)) ** 2))
    spread = float(np.var(truth))
    return error / spread if spread > 0 else error


def oracle_scores(answers: pd.DataFrame, frame: pd.DataFrame) -> dict[str, float]:
    """The oracle's headline scores on ``frame``'s rows: force and stretch R² (the MSE,
    where a level is constant), contact accuracy, x and y accuracy over contacts."""
    from eskin.evaluation.tasks import get_task

    force = get_task(ONE_CONTACT.name, "force").target_values(frame)["force"]
    stretch = frame["stretch"].to_numpy()
    touching = contact_mask(frame)
    out = {f"{name}_mse": mse_over_variance(truth, answers[name].to_numpy())
           for name, truth in (("force", force), ("stretch", stretch))}
    out["contact_accuracy"] = float(np.mean(answers["contact"].to_numpy() == touching))
    for axis in ("x", "y"):
        out[f"{axis}_accuracy"] = (float(np.mean(answers[axis].to_numpy()[touching]
                                                 == frame[axis].to_numpy()[touching]))
                                   if touching.any() else float("nan"))
    return out


def convergence(frame: pd.DataFrame, params: SkinParams, stretches, forces, *,
                skin: AnySkin = PAPER_SKIN, grid: Grid = FINE, rows: int = 200,
                seed: int = 0) -> dict[str, float]:
    """How far each score moves when the grid is doubled, on ``rows`` seeded rows of
    ``frame``; the bound has converged when no move reaches :data:`CONVERGED`.

    Force and stretch are compared as MSE over the target's variance (a move in R²)."""
    sample = frame.sample(min(rows, len(frame)), random_state=seed).reset_index(drop=True)
    scores = [oracle_scores(posterior_predictions(sample, params, stretches, forces,
                                                  skin=skin, grid=g), sample)
              for g in (grid, grid.doubled())]
    return {name: abs(scores[0][name] - scores[1][name]) for name in scores[0]
            if not np.isnan(scores[0][name])}
