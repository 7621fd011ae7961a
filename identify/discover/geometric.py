"""Discovery on absolute readings: which geometric effects the user's model misses
(`calbench discover LOG --geometry`, docs/geometry.md).

WHY A MODE OF ITS OWN. `calbench discover` tests candidates on deflections (loaded minus
unloaded readings), in which the geometry cancels to first order: a joint offset of 2 mrad moves
both readings of a pose by the same millimetres. Geometric effects are seen only in the absolute
readings, with the tracker registration inside the model, as `identify --geometry` fits them
(identify/geometry/). So the readings choose the library: ``--geometry`` asks for the absolute
ones, as it does for identify, and the candidates are the effects the registry puts in
discovery on absolute readings (``register_effect(..., readings="absolute")``,
bench/model/effects/geometric.py): all joint offsets as one candidate, the frame of each body an
actuated joint turns, the reflectors' common offset. A flag rather than an automatic switch:
every real campaign's absolute readings disagree with its nominal model beyond noise (the UR10's
by 0.7 mm), so the switch would always be on; `calbench import` already says so when its rigid
registration leaves more than the noise.

THE STARTING MODEL is the user's, fitted as identify fits it: the tracker registration (the base
frame in the tracker frame: `base_frame`, never a candidate, since an arm off its drawn place is
the registration) and the joint compliances under the robot's own weight
(identify/geometry/model.py), the complete model's parameters with every geometric effect absent.

A CANDIDATE is a group of the complete model's parameters (:func:`library`), REDUCED to its share
of the complete model's base set (:func:`global_base`, :func:`reduced`): the parameters that raise
the rank of the column-scaled Jacobian over every parameter before them in the base set's priority
order (identify/geometry/fit.py: base, tool, joint offsets, compliances, then the link frames from
the base out), named or not. So the classic redundancies (a body's z-turn and its joint's offset;
a joint's offset and the turn of the next body's frame about that joint's axis; consecutive
parallel axes, where a body's shift along them is the next one's; the base against the first
joint; the last joint's offset against a probe off its axis) are reduced once, whichever
candidate is tried first, and no two candidates share a direction of the readings: an error is
named by the effects that own its share in the base set, as identify --geometry reports it, and
never ties over a redundancy. The parameters left out are reported with the base-set parameters
they move the readings as (:func:`redundancies`). A candidate's fit starts from the current
model's values with its parameters at zero (absent): the readings are near linear in millimetres
and milliradians, so Levenberg-Marquardt from there converges, and the multi-start of
identify/discover/search.py (for effects whose deflections are not) is not needed.

THE TEST is discovery's own (identify/discover/decide.py compare): the readings' sigma is known,
the likelihood ratio is the chi2 drop, k the parameters the candidate adds, every candidate of a
round tested at the family-wise ALPHA_NAMING (Bonferroni over the round) and accepted when BIC
prefers it too; the best accepted one (BIC gain) is named and the next round tests the rest on top
of it. One rule of deflection discovery is left out: there an accepted candidate must also remove
MIN_EXPLAINED (half) of the excess chi2 or leave a fit within the noise, so that an effect that
only nibbles at a misfit it cannot explain is not named. Here the reduced candidates share no
direction, a real robot's misfit is the sum of several of them (offsets, two link frames, the
probe), and each one's LR is its own share: a link frame that explains a third of the misfit is
one of three effects. What guards against a candidate named early for a share that later ones
explain better is a BACKWARD pass instead: once no candidate is accepted, each named one is
tested for removal from the final model (the same test, Bonferroni over the named ones) and the
least needed one that fails is dropped, until all pass. A near-tie (decide.near_ties) that stays
one once the best is in the model is `ambiguous`; a misfit beyond noise with nothing accepted is
`unexplained`. Nothing here knows any particular effect but by the parameter groups of the
complete model.

THE LEVEL OF THE WHOLE VERDICT. A campaign with nothing to name (the start model true) says
something in two ways: a candidate named in the first round, or `unexplained` (the start model's
chi2 test fails and nothing is accepted). Each test has its own level, and the chance that either
speaks is at most their sum (the union bound). The issue asks for at most 0.1 % false alarms, and
asks that it be SHOWN: the 95 % Clopper-Pearson bound of the measured rate must be <= 0.1 %,
which 3000 quiet campaigns give and a single alarm in them does not (4750 campaigns per alarm
more). A test at exactly 1e-3 alarms 3 times in 3000 null campaigns on average, so its rate,
though right, could never be shown within reach (measured: 2 alarms in the first 1210 null
campaigns at 1e-3). So the whole verdict's level is ALPHA_GEOMETRY = 1e-4, a tenth of the issue's
bound, split in two halves: the first round's LR tests at ALPHA_NAMING = 5e-5 family-wise
(Bonferroni over its candidates) and the start model's chi2 at ALPHA_UNEXPLAINED = 5e-5. The
price is small: the LR a 6-parameter candidate needs rises from 29 to 34 (of 7 candidates), while
a 1 mm effect seen by a 20 um tracker has an LR in the thousands. Discovery on deflections keeps decide.py's ALPHA_EFFECT and stats.py's ALPHA_FIT (1e-3
each); here :func:`_compare` re-reads decide.compare's p-value at ALPHA_NAMING. Later rounds and
the backward pass use the same ALPHA_NAMING: they only run once something has been named, so they
add nothing to a null campaign's level. Measured: benchmarks/geometry_discover_bench.py, 3000
null campaigns (docs/geometry.md).

Units: SI (m, rad, rad/(N*m)).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from calbench.bench.core import sink
from calbench.bench.model.effects import Effect
from calbench.identify.geometry import (
    GeometricModel,
    GeometryFit,
    calibrate,
    extend_base,
    in_priority,
    kind,
    rank_rule,
    refresh_torques,
)

from .decide import AMBIGUOUS_BIC, AMBIGUOUS_SPREAD, compare, near_ties
from .stats import chi2_p

UNEXPLAINED = "unexplained"
AMBIGUOUS = "ambiguous"
# the user's model: registration, compliances and its compensator springs (statics.py)
START_EFFECTS = ("base_frame", "joint_compliance", "compensator")
REDUNDANT_SHARE = 1e-6  # a base-set column's share of a redundant one below which it is not named
ALPHA_GEOMETRY = 1e-4  # a null campaign's chance of any verdict (named or unexplained): the sum of
ALPHA_NAMING = ALPHA_GEOMETRY / 2  # the LR tests of a round (family-wise, Bonferroni) and
ALPHA_UNEXPLAINED = ALPHA_GEOMETRY / 2  # the start model's chi2 test (module docstring)


def _compare(base, cand, n_candidates: int) -> dict:
    """decide.compare with its significance at ALPHA_NAMING (Bonferroni over ``n_candidates``)."""
    st = compare(base, cand, n_candidates)
    alpha = ALPHA_NAMING / max(n_candidates, 1)
    st["alpha"] = alpha
    st["significant"] = bool(st["k"] > 0 and st["p_lr"] < alpha)
    return st


@dataclass(frozen=True)
class Candidate:
    """One candidate: the registry's effect (its name and structural options) and its parameters
    in the complete model's vector."""

    effect: Effect
    indices: tuple[int, ...]

    @property
    def label(self) -> str:
        d = self.effect.detail
        return self.effect.name + (f"[{d}]" if d else "")


@dataclass
class Scored:
    """A fit with what decide.compare reads of it (chi2, free parameters, residual count, dof,
    whitened residual) and the candidates it holds."""

    fit: GeometryFit
    labels: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict)

    @property
    def chi2(self) -> float:
        return self.fit.chi2

    @property
    def residual_w(self) -> np.ndarray:
        return self.fit.residual_w

    @property
    def n_free(self) -> int:
        return len(self.fit.free)

    @property
    def n_res(self) -> int:
        return int(self.fit.residual_w.size)

    @property
    def dof(self) -> int:
        return self.n_res - self.n_free


def group(model: GeometricModel, effect: Effect, bodies) -> tuple[int, ...]:
    """The complete model's parameters of a registry effect with its options: ``joint_offset``
    every joint's offset, ``link_geometry[body]`` the six numbers of the frame of the joint
    ``bodies`` (the bodies the actuated joints turn, in order) puts that body at, ``tool_frame``
    the probe point, ``base_frame`` the registration."""
    names = model.names
    if effect.name == "link_geometry":
        body = effect.options["link"]
        if body not in bodies:
            raise ValueError(f"link_geometry: {body!r} is not a body an actuated joint turns")
        joint = model.joints[list(bodies).index(body)]
        return tuple(i for i, n in enumerate(names) if n.startswith(joint + ".link_"))
    kinds = {"joint_offset", "tool_frame", "base_frame"}
    if effect.name not in kinds:
        raise ValueError(f"{effect.name}: not a parameter group of the geometric model")
    return tuple(i for i, n in enumerate(names) if kind(n) == effect.name)


def library(model: GeometricModel, effects: list[Effect], bodies) -> list[Candidate]:
    """The candidates: each registry effect (bench.model.effects.discovery_library(robot,
    "absolute")) as its parameter group (:func:`group`)."""
    return [Candidate(e, group(model, e, bodies)) for e in effects]


@dataclass(frozen=True)
class Readings:
    """What discovery on absolute readings fits: commanded angles (n, dof) rad, readings (n, 3) m
    in the tracker frame, their sigma (m: one number, (n,) or (n, 3)), the gravity torques."""

    q: np.ndarray
    y: np.ndarray
    sigma: float | np.ndarray
    tau: np.ndarray


def global_base(model: GeometricModel, data: Readings, theta: np.ndarray | None = None) -> tuple[int, ...]:
    """The base set of every parameter of the complete model, taken in the priority order
    (identify/geometry/fit.py PRIORITY: base, tool, joint offsets, compliances, then the link
    frames from the base out), at ``theta`` (default: the nominal model)."""
    theta = np.zeros(model.size) if theta is None else theta
    _, jac = model.jacobian(data.q, theta, data.tau)
    jac = jac * _weights(data, jac.shape[:2])[..., None]
    return extend_base(jac, (), in_priority(model.names, range(model.size)), **rank_rule(model))


def reduced(cands: list[Candidate], base: tuple[int, ...]) -> list[Candidate]:
    """Each candidate with only its parameters in the global base set (:func:`global_base`): those
    that raise the rank over every parameter before them in the priority order (module
    docstring). Their spans are independent: no two candidates share a direction."""
    keep = set(base)
    return [replace(c, indices=tuple(i for i in c.indices if i in keep)) for c in cands]


def start_fit(model: GeometricModel, data: Readings, base: tuple[int, ...]) -> tuple[Scored, Readings]:
    """The user's model as identify --geometry fits it: registration and compliances (their
    share of the global base set ``base``), then refitted with the torques at its own deflected
    pose (:func:`settle`)."""
    free = tuple(i for i in base if kind(model.names[i]) in START_EFFECTS)
    f = calibrate(model, data.q, data.y, sigma=data.sigma, tau=data.tau, free=free)
    return settle(Scored(f), data)


def settle(current: Scored, data: Readings) -> tuple[Scored, Readings]:
    """A named model refitted with the gravity torques at its own deflected pose and geometry
    (identify/geometry/fit.py refresh_torques), and the readings with those torques: the next
    round's candidates are fitted with them. Without it, the torques of the nominal geometry at
    the commanded pose leave ~10 um patterns (model.py) that a later round would name."""
    f, tau = refresh_torques(current.fit, data.q, data.y, data.sigma)
    return Scored(f, current.labels), replace(data, tau=tau)


def with_candidate(model: GeometricModel, data: Readings, current: Scored, cand: Candidate) -> Scored:
    """The current model plus a (reduced) candidate, fitted with the rest from the current values."""
    free = current.fit.free + tuple(i for i in cand.indices if i not in current.fit.free)
    f = calibrate(model, data.q, data.y, sigma=data.sigma, tau=data.tau, free=free, theta0=current.fit.theta)
    return Scored(f, current.labels + (cand.label,))


def without(model: GeometricModel, data: Readings, current: Scored, cand: Candidate) -> Scored:
    """The current model less a named candidate (its parameters back at zero), refitted."""
    free = tuple(i for i in current.fit.free if i not in cand.indices)
    theta = current.fit.theta.copy()
    theta[list(cand.indices)] = 0.0
    f = calibrate(model, data.q, data.y, sigma=data.sigma, tau=data.tau, free=free, theta0=theta)
    return Scored(f, tuple(lab for lab in current.labels if lab != cand.label))


def _weights(data: Readings, shape) -> np.ndarray:
    s = np.asarray(data.sigma, float)
    s = s[:, None] if s.ndim == 1 else s
    return np.broadcast_to(1.0 / s, shape)


def redundancies(model: GeometricModel, data: Readings, fit: GeometryFit, indices) -> list[dict]:
    """For each of ``indices`` outside the fit's base set: the parameters it moves the readings
    as (the least-squares combination of the Jacobian columns of the fit's base set grown by every
    other parameter in priority order, so that one it is left out for, though not named, is
    there: the probe point for the last joint's offset; ``residual_share``: what is left of its
    column, ~1e-9 or less for an exact redundancy) and their coefficients (SI ratios: d(that
    parameter) per unit of this one; ``named``: whether that parameter is in the fit)."""
    _, jac = model.jacobian(data.q, fit.theta, data.tau)
    jac = jac * _weights(data, jac.shape[:2])[..., None]
    a = jac.reshape(-1, model.size)
    order = in_priority(model.names, range(model.size))
    free = list(extend_base(jac, fit.free, order, **rank_rule(model)))
    out = []
    for i in indices:
        if i in free:
            continue
        col = a[:, i]
        size = float(np.linalg.norm(col))
        if size == 0.0:
            out.append({"parameter": model.names[i], "moves_nothing": True, "as": []})
            continue
        c, *_ = np.linalg.lstsq(a[:, free], col, rcond=None)
        share = np.abs(c) * np.linalg.norm(a[:, free], axis=0) / size
        keep = np.argsort(-share)[:4]
        terms = [[model.names[free[j]], float(c[j])] for j in keep if share[j] > REDUNDANT_SHARE]
        named = [model.names[free[j]] for j in keep if share[j] > REDUNDANT_SHARE and free[j] in fit.free]
        left = float(np.linalg.norm(col - a[:, free] @ c) / size)
        out.append({"parameter": model.names[i], "as": terms, "named": named, "residual_share": left})
    return out


def _record(cand: Candidate, st: dict | None, f: Scored | None, error: str | None = None) -> dict:
    rec: dict = {"effect": cand.effect.name, "detail": cand.effect.detail, "score": None}
    if error is not None:
        rec["error"] = error
        return rec
    rec.update(
        score=st["bic_gain"],
        lr=st["lr"],
        k=st["k"],
        p_lr=st["p_lr"],
        alpha=st["alpha"],
        explained=st["explained"],
        p_fit=st["p_fit"],
        significant=st["significant"],
        accepted=st["accept"],
        rms_after=f.fit.rms,
    )
    return rec


def _params(model: GeometricModel, f: GeometryFit, indices=None) -> list[dict]:
    pos = {i: j for j, i in enumerate(f.free)}
    idx = f.free if indices is None else [i for i in indices if i in pos]
    return [
        {
            "name": model.names[i],
            "effect": kind(model.names[i]),
            "value": model.value(i, f.theta) if hasattr(model, "value") else float(f.theta[i]),
            "std": float(np.sqrt(f.cov[pos[i], pos[i]])),
        }
        for i in idx
    ]


def _tie_records(best: Scored, tied: list[dict], n_tests: int, model, data) -> list[dict]:
    """The ties that stay ties (``tied``: decide.near_ties's records, best first, each with its
    candidate under ``_cand``): a tied candidate still accepted on top of the best explains
    something else (both are there; the next round names it) and is dropped, as
    identify/discover/workflow.py decides. (The reduced candidates share no direction, so a tie
    needs two nearly parallel ones: a plan that barely tells them apart.)"""
    keep = []
    for t in tied[1:]:
        cand = t.pop("_cand")
        st = _compare(best, with_candidate(model, data, best, cand), n_tests)
        t["lr_on_top_of_best"] = st["lr"]
        if not accepted(st):
            keep.append(t)
    tied[0].pop("_cand", None)
    return [tied[0], *keep] if keep else []


def accepted(st: dict) -> bool:
    """Discovery's test (decide.compare: the Bonferroni LR test and BIC) without its share rule
    (module docstring: a candidate's LR is its own share of the misfit here)."""
    return bool(st["significant"] and st["bic_gain"] > 0)


def _round(model, data, current: Scored, todo: list[Candidate], bar, name: str) -> list[tuple]:
    """Every candidate of a round fitted on top of the current model and tested: (candidate, fit,
    statistics, record), the fit and statistics None where it could not be fitted."""
    bar.start(len(todo), name)
    out = []
    for c in todo:
        if not c.indices:
            out.append(
                (c, None, None, _record(c, None, None, "no parameter outside the span of those before it"))
            )
        else:
            try:
                f = with_candidate(model, data, current, c)
                st = _compare(current, f, len(todo))
                st["accept"] = accepted(st)
                out.append((c, f, st, _record(c, st, f)))
            except (ValueError, np.linalg.LinAlgError) as exc:
                out.append((c, None, None, _record(c, None, None, str(exc))))
        bar.update(f"{name}: {c.label}")
    return out


def _backward(
    model, data, current: Scored, named: list[Candidate]
) -> tuple[Scored, Readings, list[dict], list]:
    """The backward pass: each named candidate tested for removal from the final model (the same
    test, Bonferroni over the named ones); the least needed one that fails is dropped and the
    pass repeats. A candidate named early for a share a later pair explains better goes here."""
    records, fits = [], []
    while len(named) > 0:
        tests = []
        for c in named:
            less = without(model, data, current, c)
            st = _compare(less, current, len(named))
            tests.append((st["lr"], c, less, st))
        lr, c, less, st = min(tests, key=lambda t: t[0])
        if accepted(st):
            break
        named = [n for n in named if n is not c]
        current, data = settle(less, data)
        rec = {"effect": c.effect.name, "detail": c.effect.detail, "lr": lr, "k": st["k"], "p_lr": st["p_lr"]}
        records.append(rec)
        fits.append(("without " + c.label, current))
    return current, data, records, fits


def discover_geometry(
    model: GeometricModel,
    data: Readings,
    cands: list[Candidate],
    max_rounds: int | None = None,
    progress=None,
) -> tuple[dict, list[tuple[str, Scored]]]:
    """The search (module docstring) on one point's absolute readings. Returns the report (named
    effects, steps, rounds with every candidate's statistics, the final parameters and the
    redundancies of the named effects' parameters) and the fits by label: ``start``, then the
    model after each naming (the candidate's label) and after each backward drop."""
    t0 = time.perf_counter()
    base = global_base(model, data)
    full = {c.label: c for c in cands}
    cands = reduced(cands, base)
    by_label = {c.label: c for c in cands}
    current, data = start_fit(model, data, base)
    fits = [("start", current)]
    named: list[str] = []
    chosen: list[Candidate] = []
    steps: list[dict] = []
    rounds: list[dict] = []
    ambiguous: list[dict] = []
    bar = sink(progress)
    for rnd in range(len(cands) if max_rounds is None else max_rounds):
        todo = [c for c in cands if c.label not in current.labels]
        if not todo:
            break
        results = _round(model, data, current, todo, bar, f"round {rnd + 1}")
        rounds.append(
            {
                "round": rnd + 1,
                "rms_before": current.fit.rms,
                "chi2_before": current.chi2,
                "candidates": sorted(
                    [r[3] for r in results],
                    key=lambda r: -(r["score"] if r["score"] is not None else -np.inf),
                ),
            }
        )
        ok = [r for r in results if r[2] is not None and r[2]["accept"]]
        if not ok:
            if chi2_p(current.chi2, current.dof) < ALPHA_UNEXPLAINED:
                named.append(UNEXPLAINED)
                steps.append({"effect": UNEXPLAINED, "detail": "no candidate explains the remaining misfit"})
            break
        best = max(ok, key=lambda r: r[2]["bic_gain"])
        ties = near_ties(
            (best[0].label, best[1], best[2]),
            [(r[0].label, r[1], r[2]) for r in results if r is not best and r[1] is not None],
        )
        if ties:
            for t in ties:
                t["_cand"] = by_label[t["candidate"]]
            ties = _tie_records(best[1], ties, len(todo), model, data)
        if ties:
            ambiguous.append({"round": rnd + 1, "candidates": ties})
            named.append(AMBIGUOUS)
            steps.append({"effect": AMBIGUOUS, "detail": " or ".join(t["candidate"] for t in ties)})
            rounds[-1]["ambiguous"] = [t["candidate"] for t in ties]
            break
        c, st = best[0], best[2]
        named.append(c.effect.name)
        chosen.append(c)
        before = current.fit.rms
        current, data = settle(best[1], data)
        fits.append((c.label, current))
        steps.append(
            {
                "effect": c.effect.name,
                "detail": c.effect.detail,
                "rms_before": before,
                "rms_after": current.fit.rms,
                "parameters_at_naming": _params(model, current.fit, c.indices),
                **{k: st[k] for k in ("lr", "k", "p_lr", "alpha", "bic_gain", "explained", "p_fit")},
            }
        )
        rounds[-1]["named"] = c.label
    current, data, dropped, back = _backward(model, data, current, chosen)
    fits += back
    for d in dropped:
        named.remove(d["effect"])
        for s in steps:
            if s["effect"] == d["effect"] and s.get("detail") == d["detail"]:
                s["dropped"] = d
    final = current.fit
    for s in steps:
        if s["effect"] not in (UNEXPLAINED, AMBIGUOUS) and "dropped" not in s:
            s["parameters"] = _params(model, final, by_label[_label(s)].indices)
    held = [i for lab in current.labels for i in full[lab].indices]
    start = fits[0][1].fit
    rep = {
        "method": "geometry",
        "named_effects": named,
        "steps": steps,
        "rounds": rounds,
        "ambiguous": ambiguous,
        "dropped": dropped,
        "candidates": rounds[0]["candidates"] if rounds else [],
        "start_model": {
            "effects": list(START_EFFECTS),
            "parameters": _params(model, start),
            "rms": start.rms,
            "chi2": start.chi2,
            "dof": fits[0][1].dof,
            "p": chi2_p(start.chi2, fits[0][1].dof),
        },
        "rms_before": start.rms,
        "rms_after": final.rms,
        "chi2_before": start.chi2,
        "dof_before": fits[0][1].dof,
        "p_before": chi2_p(start.chi2, fits[0][1].dof),
        "chi2_after": final.chi2,
        "dof_after": current.dof,
        "p_after": chi2_p(final.chi2, current.dof),
        "parameters": _params(model, final),
        "redundancies": redundancies(model, data, final, held),
        "decision_rule": {
            "alpha_total": ALPHA_GEOMETRY,
            "alpha_effect_familywise": ALPHA_NAMING,
            "bonferroni_over": "the round's candidates",
            "alpha_fit": ALPHA_UNEXPLAINED,
            "min_explained_share": None,
            "backward": "each named effect tested for removal, Bonferroni over the named ones",
            "score": "BIC gain = LR - k ln n",
            "ambiguous_bic": AMBIGUOUS_BIC,
            "ambiguous_lr_spread": AMBIGUOUS_SPREAD,
        },
        "n_readings": len(data.q),
        "seconds": time.perf_counter() - t0,
    }
    return rep, fits


def _label(step: dict) -> str:
    return step["effect"] + (f"[{step['detail']}]" if step["detail"] else "")


__all__ = [
    "ALPHA_GEOMETRY",
    "ALPHA_NAMING",
    "ALPHA_UNEXPLAINED",
    "AMBIGUOUS",
    "Candidate",
    "Readings",
    "START_EFFECTS",
    "Scored",
    "UNEXPLAINED",
    "discover_geometry",
    "group",
    "library",
    "redundancies",
    "start_fit",
    "with_candidate",
]
