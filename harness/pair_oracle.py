"""The Bayes bound of a two-contact scene: the best any model could do, one reading at a time.

The oracle knows the simulator (:mod:`eskin.device.physics`) and the plan's conditions
(every pair of nodes, every force for each contact; contact 1 is the pair's lower node, as
the plan labels it), each as likely as the others. Each contact lands with its own
placement offset (x and y) and seating, six latents in all, which the oracle cannot see
and integrates out per reading and condition:

* **The mode.** Damped Gauss–Newton finds the latents (in SD units, standard normal prior;
  the offsets clipped as the simulator clips them) that best explain the reading, for
  every condition at once, from a tight and from a loose seating (a seated weight's
  likelihood is flat in its seating, so one start cannot see the other side). Its Laplace
  estimate of the marginal ranks the conditions, and those more than
  e^-:data:`PRUNE_LOG` below a reading's best are dropped.
* **The integral.** The survivors are integrated by adaptive importance sampling on
  scrambled Sobol points: from Gaussians around the mode (the inverse Gauss–Newton
  Hessian widened by ``inflate``, and the same with the seatings at their prior's width),
  and from Gaussians fitted, round by round, to the weighted points drawn so far. Unlike a
  product grid (6 dimensions: 5 points an axis is 15,625 a condition, and the likelihood
  of a heavy weight's placement is about a fifth of an SD wide) its cost does not grow
  with the dimension. Every answer is also made from each half of the points
  (:func:`convergence`): how far a score moves from half the points to all of them, over
  every sample, is what the integral has not resolved.
* **The reading.** Given the latents, a reading (in pF) is Gaussian per channel, as in
  :mod:`harness.oracle` (noise, the trial's baseline offset, the random walk up to the
  sample's index, the ADC step).

Its decisions are Bayes-optimal for each metric — the posterior mean of each force (least
squares), the most probable value of each of x1, y1, x2, y2 — so where its integrals have
converged, no model predicting one reading at a time can beat it on average. Where they
have not, the oracle decides from a wrong posterior, and its scores fall *below* the true
bound: an unconverged bound errs towards models beating it, which `make bench` would show.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.special import logsumexp, ndtri
from scipy.stats import qmc

from eskin.data.plan import two_force_plan
from eskin.device.physics import SkinModel, SkinParams, spread_kernel
from eskin.kinds import TWO_CONTACTS
from eskin.skin import PAPER_SKIN, AnySkin
from harness.oracle import counts_to_pf, mse_over_variance, reading_variance

LATENTS = 6        # per contact: placement offset x, y (SDs) and seating (SDs of its log)
PRUNE_LOG = 25.0   # conditions this far (Laplace, log posterior) below a reading's best drop
ITERATIONS = 25    # Gauss–Newton steps (each accepted or damped per reading and condition)
STEP = 1e-4        # forward-difference step of the Jacobian, in SDs
SEATING_STARTS = (0.0, 1.5)  # SDs: each descent starts from each (see _modes)
SEATINGS = [2, 5]  # the seating latents' columns (each contact's offset x, y, then seating)
ADAPTATIONS = 4    # rounds of fitting a Gaussian to the weighted points (see _importance)
HALVES = ("all", "first half", "second half")  # the points each estimate uses
POSITIONS = tuple(TWO_CONTACTS.node_columns)


@dataclass(frozen=True)
class Sampling:
    """How the survivors are integrated: Sobol points per condition and the widening of the
    Laplace covariance the points are drawn from."""

    points: int = 16384
    inflate: float = 1.5


@dataclass(frozen=True)
class PairConditions:
    """The plan's conditions, one row each: stretch, and per contact node and force."""

    stretch: np.ndarray
    x1: np.ndarray
    y1: np.ndarray
    force1: np.ndarray
    x2: np.ndarray
    y2: np.ndarray
    force2: np.ndarray

    def __len__(self) -> int:
        return len(self.stretch)


def pair_conditions(stretches, forces, nodes_x, nodes_y) -> PairConditions:
    """The two-force plan's conditions (:func:`eskin.data.plan.two_force_plan`); each
    has the same number of samples, so the prior is uniform."""
    plan = two_force_plan("bound", stretches, forces, nodes_x, nodes_y, 1)
    rows = [(c.stretch, a.x, a.y, a.force, b.x, b.y, b.force)
            for c in plan.conditions for a, b in [c.contacts]]
    columns = [np.array(col) for col in zip(*rows, strict=True)]
    return PairConditions(*columns)


class PairSkin:
    """The skin's mean reading for many (condition, latents) at once — the arithmetic of
    :meth:`SkinModel.capacitance`, vectorised (a test holds the two equal)."""

    def __init__(self, model: SkinModel) -> None:
        self.model, self.params = model, model.params

    def _peak(self, newtons: np.ndarray, stretch: np.ndarray, seating: np.ndarray) -> np.ndarray:
        p = self.params
        half = p.force_half_n * stretch ** p.stretch_stiffening
        ratio = (np.maximum(newtons, 0.0) / half) ** p.force_hill
        if p.seating_force_n > 0:
            pressing = np.minimum(1.0, (newtons / (p.seating_force_n * seating)) ** (2 / 3))
        else:
            pressing = np.ones_like(newtons)
        return np.where(newtons > 0, p.strain_max * pressing * ratio / (1 + ratio), 0.0)

    def _field(self, x, y, newtons, stretch, latents) -> np.ndarray:
        p = self.params
        offsets = np.clip(p.placement_sd_nodes * latents[:, :2], -p.placement_max_nodes,
                          p.placement_max_nodes)
        seating = np.exp(p.seating_variation * latents[:, 2])
        peak = self._peak(newtons, stretch, seating)
        m = self.model
        wx = spread_kernel(m.x_nodes[None, :] - (x + offsets[:, 0])[:, None], p.reach_nodes)
        wy = spread_kernel(m.y_nodes[None, :] - (y + offsets[:, 1])[:, None], p.reach_nodes)
        return peak[:, None, None] * wx[:, :, None] * wy[:, None, :]

    def means(self, cond: PairConditions, which: np.ndarray, latents: np.ndarray) -> np.ndarray:
        """Mean readings in pF, (len(which), terminals), for condition ``which[k]`` with latents
        ``latents[k]`` (contact 1's three, then contact 2's)."""
        p, m = self.params, self.model
        stretch = cond.stretch[which]
        field = (self._field(cond.x1[which], cond.y1[which], cond.force1[which], stretch,
                             latents[:, :3])
                 + self._field(cond.x2[which], cond.y2[which], cond.force2[which], stretch,
                               latents[:, 3:]))
        field = np.minimum(field * m.node_sensitivity, p.strain_max)
        gain = 1.0 / (1.0 - field) - 1.0
        indentation = np.concatenate([gain.mean(axis=2), gain.mean(axis=1)], axis=1)
        stretched = m.baseline_pf * (1 + m.stretch_sensitivity * (stretch[:, None] - 1))
        return stretched * (1 + indentation)


def _log_likelihood(reading: np.ndarray, inverse: np.ndarray, means: np.ndarray) -> np.ndarray:
    """log p(reading | mean) up to the constant every condition shares."""
    return -0.5 * (((reading - means) ** 2) * inverse).sum(axis=-1)


def _descend(skin: PairSkin, cond: PairConditions, which: np.ndarray, reading: np.ndarray,
             scale: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Damped Gauss–Newton from ``t``: (mode, cost there, Hessian), one per item."""
    damping = np.full(len(which), 1e-3)
    eye = np.eye(LATENTS)

    def objective(latents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        residual = (reading - skin.means(cond, which, latents)) * scale
        return residual, 0.5 * ((residual ** 2).sum(1) + (latents ** 2).sum(1))

    def hessian(residual: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        jac = np.stack([(objective(t + STEP * eye[k])[0] - residual) / STEP
                        for k in range(LATENTS)], axis=2)  # d residual / d t: (M, 20, 6)
        return np.einsum("mci,mcj->mij", jac, jac) + eye, jac

    t = t.copy()
    residual, cost = objective(t)
    for _ in range(ITERATIONS):
        h, jac = hessian(residual)
        gradient = np.einsum("mci,mc->mi", jac, residual) + t
        step = np.linalg.solve(h + damping[:, None, None] * eye, -gradient[..., None])[..., 0]
        trial_residual, trial_cost = objective(t + step)
        better = trial_cost < cost
        t[better] += step[better]
        residual[better], cost[better] = trial_residual[better], trial_cost[better]
        damping = np.where(better, damping / 3, damping * 10)
    return t, cost, hessian(residual)[0]


def _modes(skin: PairSkin, cond: PairConditions, readings: np.ndarray, inverse: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per start of :data:`SEATING_STARTS`, reading and condition: where the descent ended
    (S, R, C, 6), the log posterior there (S, R, C) and the Gauss–Newton Hessian
    (S, R, C, 6, 6), prior included.

    A seated weight's likelihood is flat in its seating below the load that seats it, so
    a descent that starts there cannot tell whether a looser seating explains the reading
    better, and one that starts loose may stop short of the flat side: both are kept."""
    n_rows, n_cond = len(readings), len(cond)
    which = np.tile(np.arange(n_cond), n_rows)
    reading = np.repeat(readings, n_cond, axis=0)
    scale = np.sqrt(np.repeat(inverse, n_cond, axis=0))
    ends = []
    for seating in SEATING_STARTS:
        start = np.zeros((len(which), LATENTS))
        start[:, SEATINGS] = seating
        mode, cost, hessian = _descend(skin, cond, which, reading, scale, start)
        ends.append((mode.reshape(n_rows, n_cond, LATENTS), -cost.reshape(n_rows, n_cond),
                     hessian.reshape(n_rows, n_cond, LATENTS, LATENTS)))
    return tuple(np.stack(part) for part in zip(*ends, strict=True))


def _mixture_draw(skin: PairSkin, cond: PairConditions, i: int, reading: np.ndarray,
                  inverse: np.ndarray, components: list[tuple[np.ndarray, np.ndarray]],
                  normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Equal shares of ``normals`` through each Gaussian (mean, Cholesky factor): the
    latents, their log importance weights against the components' mixture, and which
    points are in the first half of their component's share (:data:`HALVES`)."""
    shares = np.array_split(np.arange(len(normals)), len(components))
    latents = np.concatenate([mean + normals[share] @ chol.T
                              for (mean, chol), share in zip(components, shares, strict=True)])
    first = np.concatenate([np.arange(len(share)) < len(share) // 2 for share in shares])
    log_q = [-0.5 * (np.linalg.solve(chol, (latents - mean).T) ** 2).sum(0)
             - np.log(np.diag(chol)).sum() for mean, chol in components]
    log_proposal = logsumexp(np.stack(log_q), axis=0) - np.log(len(components))
    means = skin.means(cond, np.full(len(latents), i), latents)
    log_prior = -0.5 * (latents ** 2).sum(1)  # the 2π terms cancel against the proposal's
    return latents, _log_likelihood(reading, inverse, means) + log_prior - log_proposal, first


def _fitted(latents: np.ndarray, log_weights: np.ndarray, inflate: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """A Gaussian (mean, Cholesky factor widened by ``inflate``) fitted to weighted points."""
    share = np.exp(log_weights - logsumexp(log_weights))
    mean = share @ latents
    spread = latents - mean
    cov = (spread * share[:, None]).T @ spread + 1e-6 * np.eye(LATENTS)
    return mean, np.linalg.cholesky(cov) * inflate


def _importance(skin: PairSkin, cond: PairConditions, i: int, reading: np.ndarray,
                inverse: np.ndarray, modes: np.ndarray, hessians: np.ndarray,
                normals: np.ndarray, inflate: float) -> np.ndarray:
    """log ∫ p(reading | condition i, t) φ(t) dt by importance sampling around the modes:
    from all of ``normals``, and from each half of them (:data:`HALVES`).

    First from two Gaussians at each descent's end: N(mode, inflate² H⁻¹), and the same
    with each seating decoupled and given its prior's unit variance (a seated weight's
    likelihood is flat in its seating below the load that seats it and steep above, and a
    Hessian at that kink sees only the steep side). Then, as adaptive importance sampling
    does, in :data:`ADAPTATIONS` rounds of a sixteenth of the points, a Gaussian fitted to
    all the weighted points so far joins the mixture (offsets and seating trade off along
    curved ridges that a Hessian does not see; one round left 11 effective points of
    16,384 on a reading whose contacts share a row). Every point is weighted against its
    draw's mixture (the balance heuristic), the prior among them (defensive sampling: no
    weight exceeds the likelihood over the prior's share); the estimate is the last draw's,
    over all the points."""
    components = []
    for mode, hessian in zip(modes, hessians, strict=True):
        wide = hessian.copy()
        wide[SEATINGS, :] = 0.0
        wide[:, SEATINGS] = 0.0
        wide[SEATINGS, SEATINGS] = 1.0
        components += [(mode, np.linalg.cholesky(np.linalg.inv(h)) * inflate)
                       for h in (hessian, wide)]
    # the prior too, defensively: no weight can exceed the likelihood over its share
    components.append((np.zeros(LATENTS), np.eye(LATENTS)))
    block = len(normals) // (4 * ADAPTATIONS)
    drawn, weights = [], []
    for k in range(ADAPTATIONS):
        latents, log_weights, _ = _mixture_draw(skin, cond, i, reading, inverse, components,
                                                normals[k * block:(k + 1) * block])
        drawn.append(latents)
        weights.append(log_weights)
        components.append(_fitted(np.concatenate(drawn), np.concatenate(weights), inflate))
    _, log_weights, first = _mixture_draw(skin, cond, i, reading, inverse, components, normals)
    return np.array([logsumexp(w) - np.log(len(w))
                     for w in (log_weights, log_weights[first], log_weights[~first])])


def _laplace(log_post: np.ndarray, hessian: np.ndarray) -> np.ndarray:
    """Laplace's log marginal, up to a constant: log posterior at the mode − ½ log det H
    (the prior's normalisation is the same for every condition)."""
    return log_post - 0.5 * np.linalg.slogdet(hessian)[1]


def _log_posterior(skin: PairSkin, cond: PairConditions, readings: np.ndarray,
                   inverse: np.ndarray, normals: np.ndarray, inflate: float) -> np.ndarray:
    """log p(condition | reading), unnormalised, for a few readings, from all the points and
    from each half of them (:data:`HALVES`): (3, R, C)."""
    modes, at_mode, hessians = _modes(skin, cond, readings, inverse)
    laplace = _laplace(at_mode, hessians).max(axis=0)  # the better descent's
    log_post = np.full((len(HALVES), *laplace.shape), -np.inf)
    for r in range(len(readings)):
        for i in np.flatnonzero(laplace[r] >= laplace[r].max() - PRUNE_LOG):
            log_post[:, r, i] = _importance(skin, cond, i, readings[r], inverse[r],
                                            modes[:, r, i], hessians[:, r, i], normals, inflate)
    return log_post


@dataclass(frozen=True)
class Answers:
    """The oracle's answers from all its points, and from each half of them."""

    all: pd.DataFrame
    halves: tuple[pd.DataFrame, pd.DataFrame]


def _decide(log_post: np.ndarray, cond: PairConditions, model: SkinModel) -> pd.DataFrame:
    """Bayes decisions from log posteriors (R, C): posterior means of stretch and forces,
    the most probable value of each position (a node of ``model``'s skin)."""
    log_post = log_post - logsumexp(log_post, axis=1, keepdims=True)
    post = np.exp(log_post)
    out = {"stretch": post @ cond.stretch,
           **{force: post @ getattr(cond, force) for force in TWO_CONTACTS.force_columns}}
    for name in POSITIONS:
        nodes = model.x_nodes if name.startswith("x") else model.y_nodes
        onehot = getattr(cond, name)[:, None] == nodes[None, :].astype(int)
        out[name] = np.argmax(post @ onehot, axis=1) + 1
    return pd.DataFrame(out)


def posterior_predictions(frame: pd.DataFrame, params: SkinParams, stretches, forces,
                          nodes_x, nodes_y, *, skin: AnySkin = PAPER_SKIN,
                          sampling: Sampling = Sampling(), seed: int = 0, chunk: int = 8,
                          n_jobs: int = -1, progress=None) -> Answers:
    """The oracle's answers for each row of a scene on ``skin``: stretch, force1 and force2
    (posterior means), and x1, y1, x2, y2 (each its most probable value); and the same from
    each half of the points, which :func:`convergence` compares. Chunks of rows run in
    parallel (joblib's ``n_jobs``); each row's answer is the same however they are run."""
    from joblib import Parallel, delayed

    model = SkinModel(params, skin)
    pairs = PairSkin(model)
    cond = pair_conditions(stretches, forces, nodes_x, nodes_y)
    readings = counts_to_pf(model, frame[skin.channels].to_numpy(dtype=float))
    inverse = 1.0 / reading_variance(model, frame["sample"].to_numpy())
    normals = ndtri(qmc.Sobol(LATENTS, scramble=True, seed=seed).random(sampling.points))
    starts = range(0, len(frame), chunk)
    parts = Parallel(n_jobs=n_jobs, return_as="generator")(
        delayed(_log_posterior)(pairs, cond, readings[s:s + chunk], inverse[s:s + chunk],
                                normals, sampling.inflate) for s in starts)
    blocks = []
    for start, block in zip(starts, parts, strict=True):
        blocks.append(block)
        if progress is not None:
            progress(min(start + chunk, len(frame)), len(frame))
    log_post = (np.concatenate(blocks, axis=1) if blocks
                else np.empty((len(HALVES), 0, len(cond))))
    everything, *halves = (_decide(part, cond, model) for part in log_post)
    return Answers(everything, tuple(halves))


def oracle_scores(answers: pd.DataFrame, frame: pd.DataFrame) -> dict[str, float]:
    """The oracle's scores on ``frame``'s rows: force1 and force2 as MSE over the target's
    variance (a move in R²), and the accuracy of each of x1, y1, x2, y2."""
    from eskin.evaluation.tasks import get_task

    out = {f"{name}_mse": mse_over_variance(truth, answers[name].to_numpy())
           for name, truth in get_task(TWO_CONTACTS.name, "force").target_values(frame).items()}
    for name in POSITIONS:
        out[f"{name}_accuracy"] = float(np.mean(answers[name].to_numpy()
                                                == frame[name].to_numpy()))
    return out


def convergence(answers: Answers, frame: pd.DataFrame) -> dict[str, float]:
    """How far each score on ``frame``'s rows moves from either half of the points to all of
    them — a doubling of the importance sample, on every row; the bound has converged when
    no move reaches :data:`harness.oracle.CONVERGED`. (A half is the first, or the second,
    half of every component's share of the points: an importance sample of its own from
    the same mixture.)"""
    scores = oracle_scores(answers.all, frame)
    moves = [oracle_scores(half, frame) for half in answers.halves]
    return {name: max(abs(m[name] - value) for m in moves) for name, value in scores.items()}
