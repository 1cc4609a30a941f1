"""The Bayes bound: the best any model could do on data from the simulated skin.

An oracle that knows the simulator (:mod:`eskin.device.physics`) and the
plan's discrete conditions computes, for every single-force sample, the
posterior over conditions (stretch, force, node) from that one reading:

* the reading's mean given a condition depends on per-trial latents the
  oracle cannot see — the indenter's placement offset (x and y) and the
  load factor — which are integrated out by Gauss–Hermite quadrature;
* given the mean, a reading (in pF) is Gaussian per channel: white noise,
  the trial's baseline offset, the random walk up to this sample's index,
  and the ADC's quantisation step (as uniform noise);
* the prior is the plan's: each condition's share of the samples.

Its decisions are Bayes-optimal for each metric — the posterior mean for
stretch and force (least squares), the most probable answer for contact and
for x and y of a contact — so its scores bound what a model predicting one
sample at a time can reach. Under stratified CV a model sees the other
samples of the same trial and may beat it; under grouped CV it cannot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.special import logsumexp

from eskin.data.schema import CHANNELS
from eskin.device.physics import GRID, NODES, SkinModel, SkinParams, spread_kernel


@dataclass(frozen=True)
class Conditions:
    """Every (latent-averaged) mean reading the plan can produce, with its labels."""

    means: np.ndarray        # (conditions, latents, 20) capacitance in pF
    log_weights: np.ndarray  # (latents,) log quadrature weights
    log_prior: np.ndarray    # (conditions,)
    stretch: np.ndarray      # (conditions,)
    force: np.ndarray        # physical force, 0 when contact-free
    x: np.ndarray            # 0 when contact-free
    y: np.ndarray


def _gauss_hermite(points: int, sd: float) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights (summing to 1) for E[f(Z)], Z ~ N(0, sd²)."""
    nodes, weights = np.polynomial.hermite_e.hermegauss(points)
    return nodes * sd, weights / weights.sum()


def plan_conditions(params: SkinParams, stretches, forces, *, offset_points: int = 5,
                    load_points: int = 7) -> Conditions:
    """The conditions of a single-force plan (DESIGN §5) and their mean readings."""
    model = SkinModel(params)
    stretches = np.asarray(stretches, dtype=float)
    pressing = np.asarray([f for f in forces if f > 0], dtype=float)
    offsets, offset_w = _gauss_hermite(offset_points, params.placement_sd_nodes)
    offsets = np.clip(offsets, -params.placement_max_nodes, params.placement_max_nodes)
    loads, load_w = _gauss_hermite(load_points, params.load_variation)
    loads = np.exp(loads)
    if params.load_variation == 0:
        loads, load_w = np.ones(1), np.ones(1)
    if params.placement_sd_nodes == 0:
        offsets, offset_w = np.zeros(1), np.ones(1)

    # Spread of an indenter on node n with offset o, for every node/offset: (node, offset, 10)
    spread = spread_kernel(NODES[None, None, :] - (NODES[:, None, None] + offsets[None, :, None]),
                           params.reach_nodes)
    n_lat = len(offsets) ** 2 * len(loads)
    log_w = np.log(np.einsum("i,j,k->ijk", offset_w, offset_w, load_w).ravel())

    means, labels = [], []
    for stretch in stretches:
        stretched = model.baseline_pf * (1 + model.stretch_sensitivity * (stretch - 1))
        # Contact-free: one mean, whatever the latents.
        means.append(np.broadcast_to(stretched, (n_lat, 2 * GRID)))
        labels.append((stretch, 0.0, 0, 0, "free"))
        for newtons in pressing:
            peaks = np.array([model.peak_strain(newtons * load, stretch) for load in loads])
            # field[x, ox, y, oy, load, i, j] would be large; go node by node in x.
            for xi in range(GRID):
                wx = spread[xi]                                   # (ox, 10)
                field = (wx[:, None, None, None, :, None] * spread[None, :, :, None, None, :]
                         * peaks[None, None, None, :, None, None])
                # axes: (ox, y, oy, load, i, j) → strain at node (i, j)
                gain = 1.0 / (1.0 - np.minimum(field, params.strain_max)) - 1.0
                indentation = np.concatenate([gain.mean(axis=5), gain.mean(axis=4)], axis=-1)
                cap = stretched * (1 + indentation)              # (ox, y, oy, load, 20)
                for yi in range(GRID):
                    means.append(cap[:, yi].reshape(-1, 2 * GRID))  # (ox, oy, load) order
                    labels.append((stretch, newtons, xi + 1, yi + 1, "contact"))
    means = np.stack(means)
    stretch_l, force_l, x_l, y_l, kind = zip(*labels, strict=True)
    kind = np.array(kind)
    # The plan records every node at 0 N and node 0 at every force as contact-free
    # (see README, label convention): per stretch, nodes × 1 + 1 × forces such rows.
    free_share = GRID * GRID + len(forces)
    prior = np.where(kind == "free", float(free_share), 1.0)
    return Conditions(means=means, log_weights=log_w, log_prior=np.log(prior / prior.sum()),
                      stretch=np.array(stretch_l), force=np.array(force_l),
                      x=np.array(x_l), y=np.array(y_l))


def counts_to_pf(model: SkinModel, counts: np.ndarray) -> np.ndarray:
    """Invert the read-out (CAV424 + ADC) to capacitance in pF."""
    p = model.params
    volts = counts / (2**p.adc_bits - 1) * p.supply_v
    return p.cav424_ref_pf * (1 + (volts - p.cav424_offset_v) / model.cav424_gain_v)


def reading_variance(model: SkinModel, sample_index: np.ndarray) -> np.ndarray:
    """Per-sample, per-channel variance of a reading about its mean, in pF²."""
    p = model.params
    step_pf = p.cav424_ref_pf * (p.supply_v / (2**p.adc_bits - 1)) / model.cav424_gain_v
    walk = (np.asarray(sample_index, dtype=float)[:, None] + 1) * p.drift_step_pf**2
    return p.noise_pf**2 + p.drift_offset_pf**2 + walk + step_pf[None, :] ** 2 / 12


def posterior_predictions(frame: pd.DataFrame, params: SkinParams, stretches, forces, *,
                          chunk: int = 48, progress=None) -> pd.DataFrame:
    """The oracle's answers for each row: stretch, force, contact (+ probability), x, y."""
    model = SkinModel(params)
    cond = plan_conditions(params, stretches, forces)
    readings = counts_to_pf(model, frame[CHANNELS].to_numpy(dtype=float))
    variance = reading_variance(model, frame["sample"].to_numpy())
    n_cond, n_lat, _ = cond.means.shape
    means_t = cond.means.reshape(-1, 2 * GRID).T
    means_sq_t = means_t * means_t
    contact = cond.x > 0
    out = {name: np.empty(len(frame)) for name in ("stretch", "force", "contact_probability")}
    out["x"] = np.zeros(len(frame), dtype=np.int64)
    out["y"] = np.zeros(len(frame), dtype=np.int64)
    x_onehot = (cond.x[:, None] == NODES[None, :].astype(int)) & contact[:, None]
    y_onehot = (cond.y[:, None] == NODES[None, :].astype(int)) & contact[:, None]
    for start in range(0, len(frame), chunk):
        r = readings[start:start + chunk]
        inv = 1.0 / variance[start:start + chunk]
        # Σ_i (r_i − μ_i)² / v_i, with per-row v: expand the square, three products.
        quad = (r * r * inv).sum(1)[:, None] - 2.0 * (r * inv) @ means_t + inv @ means_sq_t
        loglik = -0.5 * quad.reshape(len(r), n_cond, n_lat)
        log_post = logsumexp(loglik + cond.log_weights, axis=2) + cond.log_prior
        log_post -= logsumexp(log_post, axis=1, keepdims=True)
        post = np.exp(log_post)
        out["stretch"][start:start + chunk] = post @ cond.stretch
        out["force"][start:start + chunk] = post @ cond.force
        p_contact = np.clip(post @ contact, 0.0, 1.0)  # sums of exps: 1 + 1e-16 happens
        out["contact_probability"][start:start + chunk] = p_contact
        # Localisation is asked of contacts only: the node posterior given contact.
        out["x"][start:start + chunk] = np.argmax(post @ x_onehot, axis=1) + 1
        out["y"][start:start + chunk] = np.argmax(post @ y_onehot, axis=1) + 1
        if progress is not None:
            progress(min(start + chunk, len(frame)), len(frame))
    result = pd.DataFrame(out)
    result["contact"] = result["contact_probability"] > 0.5
    return result

