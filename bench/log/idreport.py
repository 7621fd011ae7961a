"""The identification report: what ``calbench identify --json`` writes and ``calbench view
--identified`` reads (CONTRACT.md, "JSON reports").

One type for both sides: identify (identify/report/identification.py) and discover's view report
(identify/discover/workflow.py) build an :class:`IdentificationReport` and write it with
:meth:`IdentificationReport.to_json`; the viewer (bench/view/recording.py) reads it with
:meth:`IdentificationReport.read`. It lives in bench because the viewer reads it and bench
never imports identify.

The CONTRACT keys are ``method``, ``parameters`` (``name``, ``unit``, ``estimate``, ``std``,
``truth``), ``residual_rms``, ``noise_sigma`` and ``chi2_per_dof``; everything else is an
addition that readers may lean on but not require. :meth:`~IdentificationReport.from_json` is
tolerant: only ``parameters`` (each with a string ``name`` and an ``estimate``, null when not
identifiable) must be present, a missing key reads as None (or empty), keys it does not know
(the estimator's own, e.g. one-step's ``converged`` or two-step's ``step1``) are kept in
``details`` and written back at the top level, and an ``observations`` entry that does not fit
is skipped with a note in ``read_warnings``.

Units: SI (parameters in their ``unit``; deflections and residuals in m, world frame).
Vectors are tuples of floats and undefined values None, exactly as in the JSON, so a report
compares equal to itself read back.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from calbench.bench.core import InputError

Vec3 = tuple[float, float, float]


def _num(x: Any) -> float | None:
    """A finite float, or None (for None, NaN and infinities)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _vec3(v: Sequence[float] | None) -> Vec3 | None:
    return None if v is None else tuple(float(x) for x in v)  # type: ignore[return-value]


@dataclass(frozen=True)
class ParameterEstimate:
    """One row of the parameter table. ``estimate`` and ``std`` are None when the parameter is
    not identifiable (``reason`` says why); ``truth``, ``error`` (estimate - truth) and ``z``
    (error / std) are None when the log carries no truth."""

    name: str
    unit: str = ""
    estimate: float | None = None
    std: float | None = None
    truth: float | None = None
    error: float | None = None
    z: float | None = None
    identifiable: bool = True
    reason: str | None = None

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "unit": self.unit,
            "estimate": _num(self.estimate),
            "std": _num(self.std),
            "truth": _num(self.truth),
            "error": _num(self.error),
            "z": _num(self.z),
            "identifiable": bool(self.identifiable),
            "reason": self.reason,
        }


@dataclass(frozen=True)
class Outlier:
    """A (pose, reflector) deflection whose whitened residual is ``sigma`` standard deviations."""

    pose: int
    reflector: str
    sigma: float

    def to_dict(self) -> dict:
        return {"pose": self.pose, "reflector": self.reflector, "sigma": float(self.sigma)}


@dataclass(frozen=True)
class ObservationFit:
    """The model's deflection (loaded - unloaded) of one reflector in one pose, world frame, m:
    ``predicted``, and when known the ``measured`` one and ``residual`` = measured - predicted."""

    pose: int
    reflector: str
    predicted: Vec3
    measured: Vec3 | None = None
    residual: Vec3 | None = None

    def to_dict(self) -> dict:
        def listed(v: Vec3 | None) -> list[float] | None:
            return None if v is None else list(v)

        return {
            "pose": self.pose,
            "reflector": self.reflector,
            "measured": listed(self.measured),
            "predicted": list(self.predicted),
            "residual": listed(self.residual),
        }


# keys the report derives from its fields when it writes; ignored when read
_DERIVED = ("n_lost_poses", "identifiable", "unidentifiable")
_NOT_WRITTEN = ("details", "source", "read_warnings")


@dataclass(frozen=True)
class IdentificationReport:
    """What an identification found, as ``identify --json`` writes it (see the module doc)."""

    method: str | None
    parameters: tuple[ParameterEstimate, ...]
    residual_rms: float | None = None  # m, per coordinate
    noise_sigma: float | None = None  # m, the tracker's nominal per-axis sigma
    chi2_per_dof: float | None = None
    chi2: float | None = None
    dof: int | None = None
    expected_residual_rms: float | None = None  # m, what the tracker noise alone leaves
    whitened_residual_rms: float | None = None
    covariance: tuple[tuple[float | None, ...], ...] | None = None  # of the parameters, SI
    log: str | None = None
    model: str | None = None
    n_poses_planned: int | None = None
    n_poses_used: int | None = None
    lost_poses: tuple[int, ...] = ()
    truncated: bool = False
    n_observations: int | None = None
    outliers: tuple[Outlier, ...] = ()  # none screened when the threshold is None
    outlier_threshold_sigma: float | None = None
    dropped_outliers: tuple[Outlier, ...] = ()
    seconds: float | None = None
    observations: tuple[ObservationFit, ...] = ()
    details: Mapping[str, Any] = field(default_factory=dict)  # estimator-specific, JSON values
    # where it was read from and what was skipped reading it (not written)
    source: str | None = field(default=None, compare=False)
    read_warnings: tuple[str, ...] = field(default=(), compare=False)

    # -- derived views ------------------------------------------------------------------------
    @property
    def n_lost_poses(self) -> int:
        return len(self.lost_poses)

    @property
    def identifiable(self) -> dict[str, bool]:
        return {p.name: bool(p.identifiable) for p in self.parameters}

    @property
    def unidentifiable(self) -> dict[str, str]:
        """Parameter name -> why it cannot be identified from this campaign."""
        return {p.name: p.reason for p in self.parameters if p.reason is not None}

    def has_truth(self) -> bool:
        return any(p.truth is not None for p in self.parameters)

    def predictions(self) -> dict[int, dict[str, Vec3]]:
        """pose -> reflector -> predicted deflection (m, world frame)."""
        out: dict[int, dict[str, Vec3]] = {}
        for o in self.observations:
            out.setdefault(o.pose, {})[o.reflector] = o.predicted
        return out

    # -- JSON -----------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The JSON object, keys in the order identify has always written them."""
        d = {
            "method": self.method,
            "parameters": [p.to_dict() for p in self.parameters],
            "residual_rms": _num(self.residual_rms),
            "noise_sigma": _num(self.noise_sigma),
            "chi2_per_dof": _num(self.chi2_per_dof),
            "chi2": _num(self.chi2),
            "dof": self.dof,
            "expected_residual_rms": _num(self.expected_residual_rms),
            "whitened_residual_rms": _num(self.whitened_residual_rms),
            "covariance": None
            if self.covariance is None
            else [[_num(x) for x in row] for row in self.covariance],
            "log": self.log,
            "model": self.model,
            "n_poses_planned": self.n_poses_planned,
            "n_poses_used": self.n_poses_used,
            "lost_poses": list(self.lost_poses),
            "n_lost_poses": self.n_lost_poses,
            "truncated": bool(self.truncated),
            "n_observations": self.n_observations,
            "identifiable": self.identifiable,
            "unidentifiable": self.unidentifiable,
            "outliers": [o.to_dict() for o in self.outliers],
            "outlier_threshold_sigma": _num(self.outlier_threshold_sigma),
            "dropped_outliers": [o.to_dict() for o in self.dropped_outliers],
            "seconds": _num(self.seconds),
            "observations": [o.to_dict() for o in self.observations],
        }
        clash = set(self.details) & set(d)
        if clash:
            raise ValueError(f"details may not reuse report keys: {sorted(clash)}")
        return {**d, **self.details}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, allow_nan=False)

    @classmethod
    def from_json(cls, text: str, source: object = "<report>") -> IdentificationReport:
        """Parse a report (see the module doc for what may be missing). Raises InputError
        naming ``source`` and the key when it is not JSON or a present key has the wrong type."""
        try:
            doc = json.loads(text)
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise InputError(source, "file", "JSON (calbench identify --json)", str(e)) from None
        return _Reader(source).report(doc)

    @classmethod
    def read(cls, path: str | os.PathLike) -> IdentificationReport:
        """:meth:`from_json` of a file."""
        path = Path(path)
        try:
            text = path.read_text()
        except OSError as e:
            raise InputError(
                path, "file", "a readable JSON file (calbench identify --json)", e.strerror
            ) from None
        except UnicodeDecodeError as e:
            raise InputError(path, "file", "JSON (calbench identify --json)", str(e)) from None
        return cls.from_json(text, path)


class _Reader:
    """Typed access to a report's JSON values, raising InputError with the key path
    (``at`` + name, e.g. ``parameters[2].`` + ``std``)."""

    def __init__(self, source: object):
        self.source = source

    def fail(self, key: str, expected: str, got: Any) -> InputError:
        return InputError(self.source, key, expected, got)

    def number(self, doc: Mapping, name: str, at: str = "") -> float | None:
        return self.value(doc.get(name), at + name)

    def value(self, x: Any, key: str) -> float | None:
        if x is None:
            return None
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            raise self.fail(key, "a number or null", x)
        return _num(x)

    def integer(self, doc: Mapping, name: str, at: str = "") -> int | None:
        x = doc.get(name)
        if x is None:
            return None
        if isinstance(x, bool) or not isinstance(x, int):
            raise self.fail(at + name, "an integer or null", x)
        return x

    def string(self, doc: Mapping, name: str, at: str = "") -> str | None:
        x = doc.get(name)
        if x is not None and not isinstance(x, str):
            raise self.fail(at + name, "a string or null", x)
        return x

    def items(self, doc: Mapping, name: str) -> list:
        x = doc.get(name)
        if x is None:
            return []
        if not isinstance(x, list):
            raise self.fail(name, "a list", type(x).__name__)
        return x

    def parameter(self, p: Any, i: int, identifiable: Mapping, reasons: Mapping) -> ParameterEstimate:
        key = f"parameters[{i}]"
        if not isinstance(p, dict) or not isinstance(p.get("name"), str) or "estimate" not in p:
            raise self.fail(
                key,
                "an object with a string name and an estimate (a number, or null when not identifiable)",
                p,
            )
        at, name = key + ".", p["name"]
        est = self.number(p, "estimate", at)
        ident = p.get("identifiable", identifiable.get(name, est is not None))
        if not isinstance(ident, bool):
            raise self.fail(at + "identifiable", "true or false", ident)
        return ParameterEstimate(
            name=name,
            unit=self.string(p, "unit", at) or "",
            estimate=est,
            std=self.number(p, "std", at),
            truth=self.number(p, "truth", at),
            error=self.number(p, "error", at),
            z=self.number(p, "z", at),
            identifiable=ident,
            reason=self.string(p, "reason", at) if "reason" in p else reasons.get(name),
        )

    def outlier(self, o: Any, key: str) -> Outlier:
        at = key + "."
        if not isinstance(o, dict):
            raise self.fail(key, "an object {pose, reflector, sigma}", o)
        pose, refl = self.integer(o, "pose", at), self.string(o, "reflector", at)
        sigma = self.number(o, "sigma", at)
        if pose is None or refl is None or sigma is None:
            raise self.fail(key, "an object {pose, reflector, sigma}", o)
        return Outlier(pose, refl, sigma)

    @staticmethod
    def observation(o: Any) -> ObservationFit | None:
        """An observation entry, or None when it does not fit (the viewer skips those)."""
        if not isinstance(o, dict):
            return None
        pose, refl = o.get("pose"), o.get("reflector")
        if isinstance(pose, bool) or not isinstance(pose, int) or not isinstance(refl, str):
            return None
        vecs = {}
        for k in ("measured", "predicted", "residual"):
            v = o.get(k)
            ok = (
                isinstance(v, list)
                and len(v) == 3
                and all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v
                )
            )
            if v is not None and not ok:
                return None
            vecs[k] = _vec3(v) if ok else None
        if vecs["predicted"] is None:
            return None
        return ObservationFit(pose, refl, **vecs)

    def covariance(self, doc: Mapping) -> tuple[tuple[float | None, ...], ...] | None:
        c = doc.get("covariance")
        if c is None:
            return None
        if not isinstance(c, list) or not all(isinstance(r, list) and len(r) == len(c) for r in c):
            raise self.fail("covariance", "a square list of lists of numbers or null", type(c).__name__)
        return tuple(
            tuple(self.value(x, f"covariance[{i}][{j}]") for j, x in enumerate(r)) for i, r in enumerate(c)
        )

    def report(self, doc: Any) -> IdentificationReport:
        if not isinstance(doc, dict) or not isinstance(doc.get("parameters"), list):
            raise self.fail(
                "parameters",
                "a list of {name, unit, estimate, std, truth}",
                type(doc.get("parameters") if isinstance(doc, dict) else doc).__name__,
            )
        identifiable = doc.get("identifiable") if isinstance(doc.get("identifiable"), dict) else {}
        reasons = doc.get("unidentifiable") if isinstance(doc.get("unidentifiable"), dict) else {}
        params = tuple(self.parameter(p, i, identifiable, reasons) for i, p in enumerate(doc["parameters"]))
        warnings: list[str] = []
        raw_obs = doc.get("observations")
        if raw_obs is not None and not isinstance(raw_obs, list):
            warnings.append("observations: not a list, ignored")
            raw_obs = None
        fits = [self.observation(o) for o in raw_obs or []]
        if None in fits:
            warnings.append(
                f"observations: {fits.count(None)} entries without pose, reflector "
                "and a predicted [dx, dy, dz] were skipped"
            )
        lost = self.items(doc, "lost_poses")
        if not all(isinstance(p, int) and not isinstance(p, bool) for p in lost):
            raise self.fail("lost_poses", "a list of pose indices", lost)
        truncated = doc.get("truncated", False)
        if not isinstance(truncated, bool):
            raise self.fail("truncated", "true or false", truncated)
        known = (set(IdentificationReport.__dataclass_fields__) - set(_NOT_WRITTEN)) | set(_DERIVED)
        return IdentificationReport(
            method=self.string(doc, "method"),
            parameters=params,
            residual_rms=self.number(doc, "residual_rms"),
            noise_sigma=self.number(doc, "noise_sigma"),
            chi2_per_dof=self.number(doc, "chi2_per_dof"),
            chi2=self.number(doc, "chi2"),
            dof=self.integer(doc, "dof"),
            expected_residual_rms=self.number(doc, "expected_residual_rms"),
            whitened_residual_rms=self.number(doc, "whitened_residual_rms"),
            covariance=self.covariance(doc),
            log=self.string(doc, "log"),
            model=self.string(doc, "model"),
            n_poses_planned=self.integer(doc, "n_poses_planned"),
            n_poses_used=self.integer(doc, "n_poses_used"),
            lost_poses=tuple(lost),
            truncated=truncated,
            n_observations=self.integer(doc, "n_observations"),
            outliers=tuple(
                self.outlier(o, f"outliers[{i}]") for i, o in enumerate(self.items(doc, "outliers"))
            ),
            outlier_threshold_sigma=self.number(doc, "outlier_threshold_sigma"),
            dropped_outliers=tuple(
                self.outlier(o, f"dropped_outliers[{i}]")
                for i, o in enumerate(self.items(doc, "dropped_outliers"))
            ),
            seconds=self.number(doc, "seconds"),
            observations=tuple(f for f in fits if f is not None),
            details={k: v for k, v in doc.items() if k not in known},
            source=str(self.source),
            read_warnings=tuple(warnings),
        )


__all__ = ["IdentificationReport", "ParameterEstimate", "ObservationFit", "Outlier"]
