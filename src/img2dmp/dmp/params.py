"""DMP parameters (eq. 8 of Pahič et al.) and their flat-vector form.

The network of the paper outputs one flat vector per image. Its order is fixed here and
nowhere else::

    [ w[0, 0] .. w[N-1, 0],  w[0, 1] .. w[N-1, 1], ...,   # N weights of dim 0, dim 1, ...
      tau,                                                # 1 number, seconds
      g[0] .. g[d-1],                                     # goal
      y0[0] .. y0[d-1] ]                                  # start

which for N = 25 kernels and d = 2 dimensions is 50 + 1 + 2 + 2 = 55 numbers.

The four fields are NumPy arrays or torch tensors, all of one kind, of real numbers
(float or integer; booleans, complex numbers and text are refused). Python numbers and
(nested) lists given for a field are converted: to float64 NumPy arrays, or, beside
torch fields, to tensors of their floating dtype on their device. A NumPy array beside a
torch tensor is refused with an error naming both fields. :meth:`DMPParams.from_dict`
(the reader of JSON-like records) is strict: every number must be a JSON number (not a
boolean or a string), finite, and only the fields ``w``, ``tau``, ``g``, ``y0`` may be
present.

A ``DMPParams`` may carry its constants, the :class:`DMPConfig` it is a movement of
(``config``; a model's predictions, data sets, DMP files, ``fit_dmp`` and the bridges
set it). Every function that takes a ``config`` uses the carried one when given none,
and refuses a different one by name: the same numbers under other constants are another
movement (a shipped model's DMP rolled out under the paper's ``"goal-start"`` scaling
lands tens of pixels off). Operations that make new parameters (indexing, ``to_torch``,
``to_numpy``, ``affine_dmp``, ``bend_dmp``) keep it.
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._lazy import is_tensor
from .config import DMPConfig, as_config

_is_torch = is_tensor


def as_host_array(a) -> np.ndarray | None:
    """A zero-copy NumPy view of a CPU tensor or array (None for other devices/dtypes)."""
    if _is_torch(a):
        import torch

        if not a.is_cpu or a.dtype in (torch.bfloat16,) or a.is_complex():
            return None
        return a.detach().numpy()
    return np.asarray(a)


def all_finite(a) -> bool:
    """True when no element is NaN or inf.

    On the CPU one sum decides (any NaN or inf makes it non-finite); only a non-finite
    sum, which an overflow can also cause, is checked element by element. That keeps
    input validation a small fraction of a fast rollout.
    """
    x = as_host_array(a)
    if x is None:
        return bool(a.isfinite().all())
    if x.dtype.kind not in "fc":
        return True
    with np.errstate(all="ignore"):
        if np.isfinite(x.sum()):
            return True
    return bool(np.isfinite(x).all())


_FIELDS = ("w", "tau", "g", "y0")
_MAX_DEPTH = 8  # nesting of lists a parameter field may have (batch dims + 2)


def show_value(v, limit: int = 60) -> str:
    """A short JSON-style rendering of a value for an error message (``true``, ``"2.0"``)."""
    try:
        text = json.dumps(v, allow_nan=True)
    except (TypeError, ValueError):
        text = repr(v)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _is_number(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(
        x, (bool, np.bool_)
    )


def _nested_shape(what: str, v, flat: list, depth: int = 0) -> tuple:
    """Shape of nested lists of numbers, their leaves appended to ``flat``."""
    if _is_number(v):
        flat.append(v)
        return ()
    if not isinstance(v, (list, tuple)):
        raise ValueError(f"{what} must be a number or a list of numbers, got {show_value(v)}")
    if depth >= _MAX_DEPTH:
        raise ValueError(f"{what} is nested more than {_MAX_DEPTH} lists deep")
    shapes = [_nested_shape(what, x, flat, depth + 1) for x in v]
    if any(sh != shapes[0] for sh in shapes):
        raise ValueError(f"{what} is ragged: its lists have different lengths or depths")
    return (len(v), *(shapes[0] if shapes else ()))


def strict_numbers(what: str, value, *, finite: bool = True) -> np.ndarray:
    """``value`` (a number, nested lists of numbers or a real NumPy array) as float64.

    Booleans, strings, ``None`` and ragged lists are refused (``np.asarray`` would read
    ``True`` as 1 and ``"2.0"`` as 2); with ``finite`` also NaN and inf. Errors start
    with ``what`` (e.g. ``"field 'tau'"``) and show the offending value.
    """
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "iuf":
            raise ValueError(f"{what} must hold real numbers, got an array of dtype {value.dtype}")
        arr = value.astype(np.float64)
    else:
        flat: list = []
        shape = _nested_shape(what, value, flat)
        arr = np.array(flat, dtype=np.float64).reshape(shape)
    if finite and not np.isfinite(arr).all():
        idx = first_index(~np.isfinite(arr))
        at = f" at index {list(idx)}" if idx else ""
        raise ValueError(f"{what} must be finite, got {show_value(float(arr[idx]))}{at}")
    return arr


def first_index(mask) -> tuple:
    """Index of the first True element of a boolean array or tensor (C order)."""
    if _is_torch(mask):
        mask = mask.detach().cpu().numpy()
    mask = np.asarray(mask)
    return tuple(int(i) for i in np.unravel_index(int(np.argmax(mask)), mask.shape))


def _real_dtype(a) -> bool:
    if _is_torch(a):
        import torch

        return a.dtype.is_floating_point or not (a.is_complex() or a.dtype == torch.bool)
    return a.dtype.kind in "iuf"


def _coerce_fields(p) -> None:
    """Make Python numbers and lists arrays (or tensors beside tensors); refuse a mix of
    NumPy arrays and torch tensors and booleans given as numbers."""
    fields = (p.w, p.tau, p.g, p.y0)
    if all(_is_torch(v) for v in fields) or all(type(v) is np.ndarray for v in fields):
        return  # the usual case, kept to a few hundred nanoseconds
    values = dict(zip(_FIELDS, fields, strict=True))
    tensors = {k: v for k, v in values.items() if _is_torch(v)}
    arrays = {k: v for k, v in values.items() if isinstance(v, np.ndarray)}
    if tensors and arrays:
        t, a = next(iter(tensors)), next(iter(arrays))
        raise ValueError(
            f"DMPParams mixes torch tensors and NumPy arrays: {t} is a torch.Tensor, "
            f"{a} is a numpy.ndarray; make all four one kind (to_torch() or to_numpy())"
        )
    ref = next((v for v in tensors.values() if v.dtype.is_floating_point), None)
    for k, v in values.items():
        if isinstance(v, (bool, np.bool_)):
            raise ValueError(f"DMPParams.{k} must be a number, got the boolean {v!r}")
        if not isinstance(v, (np.generic, int, float, list, tuple)):
            continue
        arr = strict_numbers(f"DMPParams.{k}", v, finite=False)
        if tensors:
            import torch

            dtype = ref.dtype if ref is not None else torch.float64
            device = next(iter(tensors.values())).device
            arr = torch.as_tensor(arr, dtype=dtype, device=device)
        setattr(p, k, arr)


def _same_values(a, b) -> bool:
    """Two fields of one kind (arrays or tensors, on one device) of equal shape and values."""
    if _is_torch(a) != _is_torch(b) or tuple(a.shape) != tuple(b.shape):
        return False
    if _is_torch(a):
        return a.device == b.device and bool((a.detach() == b.detach()).all())
    return bool(np.array_equal(a, b))


def _at(idx: tuple, a) -> str:
    """``", got -1.0 at index [3]"``: the value at ``idx`` and, in a batch, where."""
    v = a[idx] if idx else a
    value = float(v.item() if hasattr(v, "item") else v)
    return f", got {value!r}" + (f" at index {list(idx)}" if idx else "")


def _cat(parts, like):
    if _is_torch(like):
        import torch

        return torch.cat(parts, dim=-1)
    return np.concatenate(parts, axis=-1)


def _swap_last(a):
    return a.transpose(-1, -2) if _is_torch(a) else np.swapaxes(a, -1, -2)


def _float_hosts(p) -> list | None:
    """NumPy views of the four fields when each is a float NumPy array or a CPU tensor
    of float32 or float64, else None."""
    torch = sys.modules.get("torch")
    hosts = []
    for a in (p.w, p.tau, p.g, p.y0):
        if type(a) is np.ndarray and a.dtype.kind == "f":
            hosts.append(a)
        elif (
            torch is not None
            and type(a) is torch.Tensor
            and a.dtype.is_floating_point
            and a.dtype.itemsize >= 4
        ):
            if not a.is_cpu:
                return None
            hosts.append(a.detach().numpy())
        else:
            return None
    return hosts


def _finite_and_positive(hosts: list | None) -> bool:
    """True when ``hosts`` (w, tau, g, y0) hold no NaN or inf and every tau is > 0: one
    finite total decides finiteness (a few microseconds for a whole batch)."""
    if hosts is None:
        return False
    with np.errstate(all="ignore"):
        total = sum(float(h.sum()) for h in hosts)
    return math.isfinite(total) and bool((hosts[1] > 0).all())


@dataclass
class DMPParams:
    """The parameters of a batch of DMPs: weights, duration, goal and start.

    Attributes
    ----------
    w : array [*batch, N, d]
        Kernel weights ``w_k`` of the forcing term (eq. 6), one column per dimension.
    tau : array [*batch]
        Temporal scaling in seconds (> 0); with the default constants it is the
        movement's duration.
    g : array [*batch, d]
        Goal position.
    y0 : array [*batch, d]
        Start position.
    config : DMPConfig or None
        The constants these numbers are a movement of (keyword only; default None: not
        known, and functions then take the ``config`` they are given, or the paper's).
        When set, ``w`` must have its ``n_kernels x n_dims``.

    The arrays may be NumPy arrays or torch tensors (all of one kind; see the module
    docstring for what is converted and what is refused).
    """

    # Any: NumPy arrays or torch tensors, whose methods a user's type checker must allow
    w: Any
    tau: Any
    g: Any
    y0: Any
    config: DMPConfig | None = field(default=None, kw_only=True, compare=False)

    def __post_init__(self) -> None:
        # NumPy scalars and Python numbers (e.g. from indexing one sample) become 0-d arrays.
        _coerce_fields(self)
        if self.config is not None and not isinstance(self.config, DMPConfig):
            raise TypeError(
                f"DMPParams.config must be a DMPConfig or None, got {type(self.config).__name__}"
            )
        self.validate()

    def __eq__(self, other) -> bool:
        """Equal values, shapes and array kinds, and constants that make the same
        movement (both None, or :func:`same_movement`): the same numbers under other
        constants are another movement. For "equal to rounding" compare
        ``to_vector()`` with ``np.allclose``."""
        if not isinstance(other, DMPParams):
            return NotImplemented
        if not same_movement(self.config, other.config):
            return False
        return all(_same_values(getattr(self, k), getattr(other, k)) for k in _FIELDS)

    __hash__ = None  # mutable arrays

    def with_config(self, config: DMPConfig | None) -> DMPParams:
        """The same arrays (not copied) labelled with other constants (None: unlabelled).

        This is how to say on purpose that the numbers are to be read under ``config``;
        a function given a ``config`` that differs from the carried one refuses it.
        """
        return DMPParams(self.w, self.tau, self.g, self.y0, config=config)

    def _values_stamp(self) -> tuple | None:
        # Which tensors, in which state, the values were last checked on: torch bumps a
        # tensor's _version at every in-place change (a write through a NumPy view of its
        # memory is the one change it cannot see).
        fields = (self.w, self.tau, self.g, self.y0)
        if not all(_is_torch(a) for a in fields):
            return None
        return tuple((id(a), a._version) for a in fields)

    def validate(self, config: DMPConfig | None = None) -> DMPParams:
        """Check shapes and values; raise ``ValueError`` naming the field at fault.

        The values of torch tensors are checked once: validating the same, unchanged
        tensors again (as :func:`img2dmp.dmp.rollout` does with parameters that were
        checked when they were made) only checks the shapes. ``config`` (default: the
        carried one) checks ``w``'s number of kernels and dimensions.
        """
        config = self.config if config is None else config
        stamp = self._values_stamp()
        if stamp is None or stamp != self.__dict__.get("_checked"):
            self._check_values()
            if stamp is not None:
                self.__dict__["_checked"] = stamp
        w, tau, g, y0 = self.w, self.tau, self.g, self.y0
        if w.ndim < 2:
            raise ValueError(f"DMPParams.w must have shape [*batch, N, d], got {tuple(w.shape)}")
        batch, n, d = tuple(w.shape[:-2]), w.shape[-2], w.shape[-1]
        if tuple(g.shape) != batch + (d,):
            raise ValueError(f"DMPParams.g has shape {tuple(g.shape)}, expected {batch + (d,)}")
        if tuple(y0.shape) != batch + (d,):
            raise ValueError(f"DMPParams.y0 has shape {tuple(y0.shape)}, expected {batch + (d,)}")
        if tuple(tau.shape) != batch:
            raise ValueError(f"DMPParams.tau has shape {tuple(tau.shape)}, expected {batch}")
        if config is not None and (n, d) != (config.n_kernels, config.n_dims):
            raise ValueError(
                f"DMPParams.w has N={n} kernels and d={d} dims, "
                f"the config expects N={config.n_kernels}, d={config.n_dims}"
            )
        return self

    def _check_values(self) -> None:
        if _finite_and_positive(_float_hosts(self)):
            return  # the usual case, in one pass: the checks below would all pass
        names = _FIELDS
        for name in names:
            a = getattr(self, name)
            if not (_is_torch(a) or isinstance(a, np.ndarray)):
                raise ValueError(
                    f"DMPParams.{name} must be an array or tensor, got {type(a).__name__} "
                    f"{show_value(a)}"
                )
            if not _real_dtype(a):
                raise ValueError(
                    f"DMPParams.{name} has dtype {a.dtype}; expected real numbers (float or int)"
                )
        # One finite total decides for all four fields at once (a few microseconds: this
        # runs for every batch a network makes); only a non-finite one, which an
        # overflow can also cause, is looked into field by field to name the culprit.
        hosts = [as_host_array(getattr(self, name)) for name in names]
        finite = False
        if all(h is not None and h.dtype.kind == "f" for h in hosts):
            with np.errstate(all="ignore"):
                finite = bool(np.isfinite(sum(float(h.sum()) for h in hosts)))
        if not finite:
            for name in names:
                a = getattr(self, name)
                if not all_finite(a):
                    bad = ~a.isfinite() if _is_torch(a) else ~np.isfinite(a)
                    idx = first_index(bad)
                    raise ValueError(f"DMPParams.{name} contains NaN or inf{_at(idx, a)}")
        tau = hosts[1] if hosts[1] is not None else self.tau
        if not bool((tau > 0).all()):
            idx = first_index(~(tau > 0))
            raise ValueError(
                f"DMPParams.tau must be > 0 (it is a duration in seconds){_at(idx, tau)}"
            )

    @property
    def batch_shape(self) -> tuple:
        return tuple(self.w.shape[:-2])

    @property
    def n_kernels(self) -> int:
        return int(self.w.shape[-2])

    @property
    def n_dims(self) -> int:
        return int(self.w.shape[-1])

    def to_vector(self) -> Any:
        """Flat vector ``[*batch, N*d + 1 + 2d]`` in the order given in the module docstring."""
        w_flat = _swap_last(self.w).reshape(*self.batch_shape, -1)
        return _cat([w_flat, self.tau[..., None], self.g, self.y0], self.w)

    @classmethod
    def from_vector(
        cls, v, n_kernels: int, n_dims: int, *, config: DMPConfig | None = None
    ) -> DMPParams:
        """Inverse of :meth:`to_vector`; ``v`` has shape ``[*batch, N*d + 1 + 2d]``;
        the result carries ``config``."""
        n, d = n_kernels, n_dims
        expected = n * d + 1 + 2 * d
        if v.shape[-1] != expected:
            raise ValueError(
                f"parameter vector has length {v.shape[-1]}, expected N*d + 1 + 2d = {expected} "
                f"for N={n}, d={d}"
            )
        batch = tuple(v.shape[:-1])
        w = _swap_last(v[..., : n * d].reshape(*batch, d, n))
        tau = v[..., n * d]
        g = v[..., n * d + 1 : n * d + 1 + d]
        y0 = v[..., n * d + 1 + d :]
        return cls(w=w, tau=tau, g=g, y0=y0, config=config)

    def to_torch(self, dtype=None, device=None) -> DMPParams:
        """The same parameters as torch tensors (``dtype`` default float64)."""
        import torch

        dtype = torch.float64 if dtype is None else dtype
        conv = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731
        return self._like(conv(self.w), conv(self.tau), conv(self.g), conv(self.y0))

    def to_numpy(self) -> DMPParams:
        """The same parameters as NumPy arrays (views of CPU tensors' memory)."""
        conv = lambda a: a.detach().cpu().numpy() if _is_torch(a) else np.asarray(a)  # noqa: E731
        return self._like(conv(self.w), conv(self.tau), conv(self.g), conv(self.y0))

    def __getitem__(self, idx) -> DMPParams:
        """Index the batch dimensions: ``params[3]``, ``params[:10]``."""
        return self._like(self.w[idx], self.tau[idx], self.g[idx], self.y0[idx])

    def __len__(self) -> int:
        """The first batch dimension (``len(pred.params)``: K); ``TypeError`` for one DMP."""
        shape = self.batch_shape
        if not shape:
            raise TypeError("len() of one DMP (batch shape ()): it is not a batch")
        return int(shape[0])

    def __iter__(self):
        """The DMPs along the first batch dimension (one DMP is not iterable)."""
        return (self[i] for i in range(len(self)))

    def __bool__(self) -> bool:
        return True  # parameters are never "empty" in a condition (not len() == 0)

    def _like(self, w, tau, g, y0) -> DMPParams:
        """New fields under these parameters' constants."""
        return DMPParams(w, tau, g, y0, config=self.config)

    def to_dict(self) -> dict:
        """JSON-ready nested lists (NumPy view)."""
        p = self.to_numpy()
        return {"w": p.w.tolist(), "tau": p.tau.tolist(), "g": p.g.tolist(), "y0": p.y0.tolist()}

    @classmethod
    def from_dict(
        cls, d: dict, *, config: DMPConfig | None = None, batch_shape: tuple | None = None
    ) -> DMPParams:
        """Inverse of :meth:`to_dict`, strict (see the module docstring).

        Errors name the field and the value at fault (``field 'tau' must be a number or a
        list of numbers, got true``). With ``config`` and ``batch_shape`` the fields'
        shapes are checked too (``batch_shape=()`` for one DMP). The result carries
        ``config``.
        """
        if not isinstance(d, dict):
            raise ValueError(
                f"DMP parameters must be an object with fields w, tau, g, y0, got {show_value(d)}"
            )
        missing = [k for k in _FIELDS if k not in d]
        if missing:
            raise ValueError(f"DMP parameters are missing field(s) {missing}")
        unknown = sorted(str(k) for k in d if k not in _FIELDS)
        if unknown:
            raise ValueError(f"DMP parameters have unknown field(s) {unknown} (only w, tau, g, y0)")
        arrs = {k: strict_numbers(f"field {k!r}", d[k]) for k in _FIELDS}
        if config is not None and batch_shape is not None:
            _check_shapes(arrs, config, tuple(batch_shape))
        tau = arrs["tau"]
        if not (tau > 0).all():
            idx = first_index(~(tau > 0))
            raise ValueError(f"field 'tau' must be > 0 (a duration in seconds){_at(idx, tau)}")
        return cls(**arrs, config=config)


_MEANING = ("n_kernels", "n_dims", "alpha_z", "beta", "alpha_x", "width_factor", "scaling")


def _meaning(config: DMPConfig) -> tuple:
    """What the constants make of a DMP's numbers (``beta_z`` None and ``alpha_z / 4``
    are one damping)."""
    return tuple(getattr(config, name) for name in _MEANING)


def same_movement(a: DMPConfig | None, b: DMPConfig | None) -> bool:
    """Whether two configs (or two None) make the same movement of the same numbers."""
    if a is None or b is None:
        return a is b
    return a is b or _meaning(a) == _meaning(b)


def config_of(params, config, default: DMPConfig | None = None) -> DMPConfig:
    """The constants to read ``params`` under: ``config``, or the ones ``params`` carries
    when ``config`` is None, or ``default`` (the paper's when None).

    A ``config`` that differs from the carried one is refused with a ``ValueError``
    naming the constants that differ: the same numbers under other constants are
    another movement, silently. ``params.with_config(config)`` relabels on purpose.
    """
    own = getattr(params, "config", None)
    if config is None or config is own:
        if own is not None:
            return own
        return as_config(config, default)
    config = as_config(config)
    if own is not None and not same_movement(config, own):
        differ = ", ".join(
            f"{name} {getattr(config, name)!r} (carried {getattr(own, name)!r})"
            for name, a, b in zip(_MEANING, _meaning(config), _meaning(own), strict=True)
            if a != b
        )
        raise ValueError(
            f"config differs from the constants these DMP parameters carry: {differ}; "
            "leave config out to use the carried ones, or relabel with "
            "params.with_config(config)"
        )
    return config


def _check_shapes(arrs: dict, config: DMPConfig, batch: tuple) -> None:
    n, d = config.n_kernels, config.n_dims
    expected = {"w": batch + (n, d), "tau": batch, "g": batch + (d,), "y0": batch + (d,)}
    meaning = {
        "w": f"n_kernels x n_dims = {n} x {d} of the DMP config",
        "tau": "one number" if not batch else "one number per DMP",
        "g": f"n_dims = {d} coordinates",
        "y0": f"n_dims = {d} coordinates",
    }
    for k, shape in expected.items():
        if arrs[k].shape != shape:
            raise ValueError(
                f"field {k!r} has shape {list(arrs[k].shape)}, expected "
                f"{list(shape)} ({meaning[k]})"
            )
