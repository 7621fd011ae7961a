"""The tracker family: a tracker station (:class:`TrackerSpec`), the error model every
``[tracker] model`` implements (:class:`TrackerModel`) and the registry of models by name.

A reading of the reflector at the tracker-frame point y (range rho = |y|, line of sight
u = y / rho), taken at t (s since the campaign's first reading), is

    y_measured = y + c(y, t) + e                                                   (1)

* e, the reading's independent error: zero mean, Cov(e) = C(y) (:meth:`TrackerModel.covariance`),
  a fresh draw for every reading (:meth:`TrackerModel.draw`); what a ``/tracker/measurement``
  carries as its covariance;
* c, the error readings share (a correlated model only, :attr:`TrackerModel.correlated`): zero
  mean, drawn once per campaign at every reading (:meth:`TrackerModel.draw_correlated`), with
      Cov(c_k, c_l) = K(y_k, t_k; y_l, t_l)                                        (2)
  (:meth:`TrackerModel.correlated_covariance`), e.g. iso10360's systematic field and drift.

Paper eq. (2) differences the means of N_u unloaded and N_l loaded readings of reflector r,
dp_r = mean_l(y) - mean_u(y); its covariance over a pose's reflectors r, s is

    Cov(dp_r, dp_s) = [r = s] sum_k C_k / N_k^2  +  sum_kl w_rk w_sl K_kl            (3)

over the pose's readings k, l (w_rk = +-1 / N, the weight of reading k in dp_r; N_k the count of
its state), bench.tracker.deflection_covariance. Poses are taken as independent (the shared part
is almost differenced away between them: bench/tracker/models/iso10360.py). A fit of absolute
positions that treats readings as independent (the registration) weights each by
C + K(y, t; y, t) (:meth:`TrackerModel.correlated_marginal`). A model whose K depends on the
readings' times (:attr:`TrackerModel.uses_times`) makes identification read them from the log's
nanosecond stamps, which only the log writer knows; a study therefore runs such a campaign
through its log rather than in memory (identify/study/campaign.py).

A model is one file in bench/tracker/models/ (its name the file's, ``MODEL`` its instance):
:func:`tracker_models` finds them there on first use; :func:`register_tracker_model` adds one from
outside (a test, a notebook). Every module that depends on the model asks the spec's
:attr:`TrackerSpec.error_model`, never its name. The three shipped models keep their parameters
in TrackerSpec's named fields (the contract's keys); a new model keeps its own in ``params``.

Units: SI (m, rad, s).
"""

from __future__ import annotations

import importlib
import math
import pkgutil
import threading
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from calbench.bench.core import InputError, Table, describe, frozen_array

DEFAULT_MODEL = "isotropic"
DEFAULT_SIGMA = 20e-6
DEFAULT_DISTANCE = (10e-6, 0.3e-6)  # Leica AT500 ADM: 10 um + 0.3 um/m
DEFAULT_TRANSVERSE = (15e-6, 6e-6)  # Leica AT500 angular: 15 um + 6 um/m
# model = "iso10360" (bench/tracker/models/iso10360.py, where each default is argued): the share of
# a reading's 1-sigma that is independent noise, the systematic field's correlation lengths, the drift.
DEFAULT_RANDOM = 0.25
DEFAULT_CORRELATION_ANGLE = math.radians(10.0)
DEFAULT_CORRELATION_RANGE = 1.0  # m
DEFAULT_DRIFT = (5e-6, 1e-6)  # m and m/m per sqrt(hour)
# the [tracker] keys every model reads (the header carries sigma, distance and transverse for all)
STATION_KEYS = ("sigma", "position", "yaw", "model", "distance", "transverse")
ROTATION_TOL = 1e-9  # |R^T R - I| and |det R - 1| of a rotation read back from JSON
MODELS_PACKAGE = "calbench.bench.tracker.models"


# --------------------------------------------------------------------------- the station


@dataclass(frozen=True)
class TrackerSpec:
    """Laser tracker placement (world frame) and error model.

    ``model`` names the error model (:func:`tracker_model`; :attr:`error_model` is it):
    ``"isotropic"`` uses ``sigma`` per axis; ``"spec"`` uses the 1-sigma distance and transverse
    errors ``a + b * range`` of an ISO 10360-10 style specification; ``"iso10360"`` splits that
    single-point error into a smooth systematic field, independent noise (the share ``random``
    of the 1-sigma) and a drift in time (bench/tracker/models/iso10360.py; ``correlation_angle``
    rad, ``correlation_range`` m, ``drift`` [a m, b m/m] per sqrt(hour)). ``params`` holds the
    parameters of a model that has keys of its own beyond these (SI, by key).

    The tracker frame is rotated by ``yaw`` about world z, or, when ``rotation`` is given (a
    registered tracker, identify/shopfloor/tracker_pose.py: any orientation), by that
    world-from-tracker matrix; ``yaw`` is then the rotation's heading, for readers that know
    only yaw.
    """

    position: np.ndarray
    yaw: float = 0.0
    model: str = DEFAULT_MODEL
    sigma: float = DEFAULT_SIGMA
    distance: tuple[float, float] = DEFAULT_DISTANCE
    transverse: tuple[float, float] = DEFAULT_TRANSVERSE
    rotation: np.ndarray | None = None
    random: float = DEFAULT_RANDOM
    correlation_angle: float = DEFAULT_CORRELATION_ANGLE
    correlation_range: float = DEFAULT_CORRELATION_RANGE
    drift: tuple[float, float] = DEFAULT_DRIFT
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def error_model(self) -> TrackerModel:
        """The registered model named ``model`` (ValueError when none is)."""
        return tracker_model(self.model)

    def to_dict(self) -> dict[str, Any]:
        """The JSON form of the log header's ``tracker`` (CONTRACT.md, ``/campaign/info``):
        SI throughout (position m, yaw rad, sigma m, ``[a m, b m/m]`` error laws; ``rotation``,
        3 rows of 3, only when set), then the model's own keys (:meth:`TrackerModel.header`)."""
        d = {
            "position": [float(x) for x in self.position],
            "yaw": float(self.yaw),
            "model": self.model,
            "sigma": float(self.sigma),
            "distance": [float(x) for x in self.distance],
            "transverse": [float(x) for x in self.transverse],
        }
        if self.rotation is not None:
            d["rotation"] = np.asarray(self.rotation, dtype=float).tolist()
        d.update(self.error_model.header(self, degrees=False))
        return d

    def to_table(self) -> dict[str, Any]:
        """The scenario's ``[tracker]`` table of this tracker, in file units (yaw and the
        model's angles in degrees, rounded to 1e-10 degree); ``rotation`` is not written (a
        scenario places its tracker by yaw)."""
        return {
            "sigma": self.sigma,
            "position": np.asarray(self.position).tolist(),
            "yaw": round(math.degrees(self.yaw), 10),
            "model": self.model,
            "distance": list(self.distance),
            "transverse": list(self.transverse),
            **self.error_model.header(self, degrees=True),
        }

    def placed(self, position: np.ndarray, rotation: np.ndarray) -> TrackerSpec:
        """This tracker (same error model) at ``position`` (m) with world-from-tracker
        ``rotation``."""
        rot = _rotation_matrix(rotation, "<rotation>", "rotation")
        return replace(
            self, position=frozen_array(position), rotation=rot, yaw=float(math.atan2(rot[1, 0], rot[0, 0]))
        )

    @classmethod
    def from_table(cls, c: Table) -> TrackerSpec:
        """A scenario's or plan's ``[tracker]`` table (yaw and the model's angles in degrees):
        only the station's keys and the registered models' keys are allowed."""
        c.only(STATION_KEYS + tuple(k for m in tracker_models().values() for k in m.keys))
        return _tracker_spec(c, degrees=True)

    @classmethod
    def from_dict(cls, d: Any, file: object = "<tracker>", key: str = "tracker") -> TrackerSpec:
        """The inverse of :meth:`to_dict`, validated like the scenario's ``[tracker]`` table but
        in SI (yaw in rad). Missing optional keys take the scenario defaults; unknown keys are
        ignored (a log header may carry more). Bad values raise InputError naming ``file`` and
        ``key.<field>``."""
        return _tracker_spec(Table(file, d, key), degrees=False)


def error_law(c: Table, name: str, default: tuple[float, float]) -> tuple[float, float]:
    """An ``[a, b]`` error law a + b*range: a > 0 keeps the covariance positive definite."""
    if not c.has(name):
        return default
    a, b = c.vector(name, 2, nonneg=True)
    if a <= 0:
        raise c.fail(name, "[a, b] with a > 0 (m) and b >= 0 (m/m)", [a, b])
    return (float(a), float(b))


def _rotation_matrix(value: Any, file: object, key: str) -> np.ndarray:
    """A proper rotation matrix (3 rows of 3 finite numbers, orthonormal, det +1), frozen."""
    try:
        rot = np.array(value, dtype=float)
    except (TypeError, ValueError):
        rot = np.zeros(0)
    ok = rot.shape == (3, 3) and bool(np.all(np.isfinite(rot)))
    if ok:
        ok = (
            np.abs(rot.T @ rot - np.eye(3)).max() < ROTATION_TOL
            and abs(np.linalg.det(rot) - 1) < ROTATION_TOL
        )
    if not ok:
        raise InputError(
            file,
            key,
            "a rotation matrix (3 rows of 3 numbers, orthonormal, det +1)",
            describe(value) if not isinstance(value, list) else value,
        )
    return frozen_array(rot)


def _tracker_spec(c: Table, degrees: bool) -> TrackerSpec:
    """A TrackerSpec from a checked table; ``degrees``: the table's angles are in degrees (a
    scenario), else in rad (a log header). A key of another model than the table's is refused
    (it would silently do nothing), naming the model it belongs to."""
    to_rad = math.radians if degrees else float
    rotation = _rotation_matrix(c.raw("rotation"), c.file, c.key("rotation")) if c.has("rotation") else None
    name = c.string("model", tuple(tracker_models())) if c.has("model") else DEFAULT_MODEL
    model = tracker_model(name)
    for other in tracker_models().values():
        for key in other.keys:
            if key not in model.keys and c.has(key):
                raise c.fail(key, f'model = "{other.name}" for this key ({other.summary})')
    own = model.parse(c, degrees)
    return TrackerSpec(
        **own,
        position=frozen_array(c.vector("position", 3)),
        yaw=to_rad(c.number("yaw")) if c.has("yaw") else 0.0,
        model=name,
        sigma=c.number("sigma", positive=True) if c.has("sigma") else DEFAULT_SIGMA,
        distance=error_law(c, "distance", DEFAULT_DISTANCE),
        transverse=error_law(c, "transverse", DEFAULT_TRANSVERSE),
        rotation=rotation,
    )


# --------------------------------------------------------------------------- the model


class TrackerModel(ABC):
    """What a ``[tracker] model`` is (the module docstring's equations (1)-(3)).

    Subclasses set :attr:`name` (the contract's model name, their file's name) and
    :attr:`summary`, and implement :meth:`covariance` and :meth:`describe`; a model with keys of
    its own lists them in :attr:`keys` and reads and writes them in :meth:`parse` and
    :meth:`header`; a correlated model sets :attr:`correlated` and implements
    :meth:`correlated_covariance` and :meth:`draw_correlated` (and :attr:`uses_times` when K
    depends on the readings' times). Models are stateless: a spec holds the parameters.
    """

    name: ClassVar[str]
    summary: ClassVar[str]  # a few words for people: what its error is
    keys: ClassVar[tuple[str, ...]] = ()  # its own [tracker] keys, beyond STATION_KEYS
    correlated: ClassVar[bool] = False  # readings share error: c of eq. (1)
    uses_times: ClassVar[bool] = False  # K depends on the readings' times (the log's stamps)
    sigma_per_axis: ClassVar[bool] = False  # every reading's error is spec.sigma on each axis

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        if cls.correlated and (
            cls.correlated_covariance is TrackerModel.correlated_covariance
            or cls.draw_correlated is TrackerModel.draw_correlated
        ):
            raise TypeError(
                f"{cls.__name__}: a correlated model implements correlated_covariance and draw_correlated"
            )

    def parse(self, c: Table, degrees: bool) -> dict[str, Any]:
        """TrackerSpec fields (SI) from the model's own keys of the ``[tracker]`` table ``c``,
        validated with ``c`` (errors name the file and key); angles in degrees when ``degrees``
        (a scenario), else rad (a log header). Default: no keys of its own."""
        return {}

    def header(self, spec: TrackerSpec, degrees: bool) -> dict[str, Any]:
        """The model's own keys of ``spec``, as :meth:`parse` reads them (angles in degrees when
        ``degrees``, rounded to 1e-10 degree): what a log header and a written scenario carry."""
        return {}

    @abstractmethod
    def covariance(self, spec: TrackerSpec, y: np.ndarray) -> np.ndarray:
        """C(y) (n, 3, 3) of eq. (1): a reading's independent error at tracker-frame points y (n, 3)."""

    def draw(
        self, spec: TrackerSpec, y: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """One reading's independent error e (n, 3) at the points y and its covariance C(y) (what
        the reading reports): e = L z, L L^T = C(y) (Cholesky), z one standard-normal (n, 3)
        block, so that every model consumes the generator by 3 n normals per reading."""
        cov = self.covariance(spec, y)
        chol = np.linalg.cholesky(cov)
        z = rng.standard_normal((len(y), 3))
        return np.einsum("nij,nj->ni", chol, z), cov

    def correlated_covariance(
        self, spec: TrackerSpec, ya: np.ndarray, ta: np.ndarray, yb: np.ndarray, tb: np.ndarray
    ) -> np.ndarray:
        """K (na, 3, nb, 3) of eq. (2) between readings at tracker-frame points ya, yb taken at
        times ta, tb (s since the campaign's first reading). Correlated models only."""
        raise NotImplementedError(f"the {self.name} tracker's readings are independent")

    def correlated_marginal(self, spec: TrackerSpec, y: np.ndarray, t: np.ndarray) -> np.ndarray:
        """K(y_k, t_k; y_k, t_k) (n, 3, 3): the shared error's share of single readings' covariance
        (zero for a model whose readings are independent)."""
        y = np.asarray(y, dtype=float)
        if not self.correlated:
            return np.zeros((len(y), 3, 3))
        k = self.correlated_covariance(spec, y, t, y, t)
        return k[np.arange(len(y)), :, np.arange(len(y)), :]

    def draw_correlated(
        self, spec: TrackerSpec, y: np.ndarray, t: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """c (n, 3) of eq. (1): one campaign's shared error at readings of the points y (n, 3)
        taken at times t (n,), drawn from eq. (2). Correlated models only."""
        raise NotImplementedError(f"the {self.name} tracker's readings are independent")

    @abstractmethod
    def describe(self, spec: TrackerSpec) -> str:
        """One line for people, in their units, e.g. "isotropic, σ = 20 µm per axis"."""


# --------------------------------------------------------------------------- the registry

_MODELS: dict[str, TrackerModel] = {}
_found = False  # bench/tracker/models/ has been read
_LOCK = threading.RLock()


def _find_models() -> dict[str, TrackerModel]:
    """The registry, after loading every module of bench/tracker/models/ once (the default model
    first, then by name) and registering its ``MODEL``, whose name must be the module's."""
    global _found
    if _found:  # the common case, without the lock: every reading asks
        return _MODELS
    with _LOCK:
        if not _found:
            package = importlib.import_module(MODELS_PACKAGE)
            names = sorted(
                m.name for m in pkgutil.iter_modules(package.__path__) if not m.name.startswith("_")
            )
            for name in sorted(names, key=lambda n: n != DEFAULT_MODEL):
                model = getattr(importlib.import_module(f"{MODELS_PACKAGE}.{name}"), "MODEL", None)
                if not isinstance(model, TrackerModel) or model.name != name:
                    raise TypeError(f"{MODELS_PACKAGE}.{name}: MODEL must be a TrackerModel named {name!r}")
                _MODELS.setdefault(name, model)
            _found = True
    return _MODELS


def tracker_models() -> dict[str, TrackerModel]:
    """Every registered model by name: bench/tracker/models/'s (the default first), then those
    registered from outside, in order. A copy."""
    return dict(_find_models())


def tracker_model(name: str) -> TrackerModel:
    """The model registered as ``name`` (ValueError naming the registered ones otherwise)."""
    models = _find_models()
    if name not in models:
        raise ValueError(f"unknown tracker noise model {name!r} (registered: {', '.join(models)})")
    return models[name]


def register_tracker_model(model: TrackerModel) -> TrackerModel:
    """Register ``model`` under its name (ValueError when the name is taken); returns it."""
    if not isinstance(model, TrackerModel):
        raise TypeError(f"a TrackerModel, got {type(model).__name__}")
    with _LOCK:
        _find_models()
        if model.name in _MODELS:
            raise ValueError(f"a tracker model named {model.name!r} is registered already")
        _MODELS[model.name] = model
    return model


def unregister_tracker_model(name: str) -> None:
    """Remove a model registered with :func:`register_tracker_model` (the shipped ones stay)."""
    with _LOCK:
        _find_models()
        package = importlib.import_module(MODELS_PACKAGE)
        if any(m.name == name for m in pkgutil.iter_modules(package.__path__)):
            raise ValueError(f"{name!r} is a model of bench/tracker/models/, not unregistered")
        _MODELS.pop(name, None)


__all__ = [
    "DEFAULT_MODEL",
    "DEFAULT_SIGMA",
    "DEFAULT_DISTANCE",
    "DEFAULT_TRANSVERSE",
    "STATION_KEYS",
    "TrackerSpec",
    "TrackerModel",
    "error_law",
    "tracker_models",
    "tracker_model",
    "register_tracker_model",
    "unregister_tracker_model",
]
