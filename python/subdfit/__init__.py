"""subdfit: dense triangle meshes to adaptive Catmull-Clark subdivision surfaces.

The same library as the ``subdfit`` command line and the C++ package, from
Python. Arrays in, results out::

    import subdfit
    mesh = subdfit.read("data/spot.ply")
    result = subdfit.convert(mesh.vertices, mesh.faces, tolerance=0.05, name=mesh.name)
    result.control.positions, result.tiles, result.metrics["accuracy.limit.rms_permille"]
    result.write("out/spot")          # the bytes `subdfit convert data/spot.ply -o out/spot` writes

Conversions release the GIL (other Python threads run meanwhile) and stop
within a few tens of milliseconds on Ctrl-C (``KeyboardInterrupt``) or when
the ``progress(stage, fraction)`` callback returns ``False``
(:class:`Cancelled`). Every error is a :class:`Error` carrying the CLI's
message; bad arrays never crash the interpreter.

This module is only the Python face: shapes and dtypes are checked here,
everything else is done by the Rust library (``_subdfit``).
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from . import _subdfit
from ._subdfit import (
    BackendError,
    Cancelled,
    Error,
    FileError,
    InternalError,
    InvalidInput,
    InvalidOption,
    NumericalError,
)

__all__ = [
    "Error", "InvalidInput", "InvalidOption", "FileError", "NumericalError", "BackendError",
    "InternalError", "Cancelled",
    "Mesh", "ControlMesh", "Conversion", "LimitPoints",
    "read", "read_control", "convert", "convert_file", "fit", "limit", "batch",
    "DEFAULT_TOLERANCE", "__version__",
]

__version__: str = _subdfit.version()

#: τ of the M-fitmap when none is given (the CLI's default, 5 %).
DEFAULT_TOLERANCE: float = _subdfit.Options().tolerance

Progress = Callable[[str, float], "bool | None"]
"""``progress(stage, fraction)``: called at most every ~20 ms, possibly from
another thread; return ``False`` to cancel (any other value goes on)."""

_U32_MAX = 2**32 - 1


# ---- arrays in --------------------------------------------------------------------


def _vertices(vertices: Any, what: str = "vertices") -> np.ndarray:
    try:
        v = np.asarray(vertices)
    except Exception as e:  # ragged lists and the like
        raise InvalidInput(f"{what}: not an array of numbers ({e})") from None
    if v.dtype.kind not in "fiu" or v.ndim != 2 or v.shape[1] != 3:
        raise InvalidInput(
            f"{what}: expected an (n, 3) array of floats, got shape {v.shape} of {v.dtype}"
        )
    # Non-finite values are the library's to report: it names the vertex.
    return np.ascontiguousarray(v, dtype=np.float64).reshape(-1)


def _indices(a: Any, what: str) -> np.ndarray:
    try:
        i = np.asarray(a)
    except Exception as e:
        raise InvalidInput(f"{what}: not an array of integers ({e})") from None
    if i.size == 0:
        return np.zeros(0, dtype=np.uint32)
    if i.dtype.kind not in "iu":
        raise InvalidInput(f"{what}: expected integers, got {i.dtype}")
    lo, hi = int(i.min()), int(i.max())
    if lo < 0 or hi > _U32_MAX:
        bad = int(np.flatnonzero((i.reshape(-1) < 0) | (i.reshape(-1) > _U32_MAX))[0])
        raise InvalidInput(f"{what}: entry {bad} is {int(i.reshape(-1)[bad])}, out of range")
    return np.ascontiguousarray(i, dtype=np.uint32).reshape(-1)


def _faces(faces: Any, face_sizes: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """(sizes, indices) from an (m, k) integer array, a list of polygons, or
    flat indices with ``face_sizes``."""
    if face_sizes is not None:
        return _indices(face_sizes, "face_sizes"), _indices(faces, "faces")
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        sizes = np.full(faces.shape[0], faces.shape[1], dtype=np.uint32)
        return sizes, _indices(faces, "faces")
    if isinstance(faces, np.ndarray) and faces.ndim != 1 or isinstance(faces, (str, bytes)):
        raise InvalidInput(
            f"faces: expected an (m, k) integer array or a list of polygons, got shape "
            f"{np.shape(faces)}"
        )
    try:
        polys = [np.asarray(f).reshape(-1) for f in faces]
    except TypeError:
        raise InvalidInput("faces: expected a list of polygons (sequences of vertex indices)") from None
    sizes = np.fromiter((len(p) for p in polys), dtype=np.uint32, count=len(polys))
    flat = np.concatenate(polys) if polys else np.zeros(0, dtype=np.int64)
    return sizes, _indices(flat, "faces")


def _weights(a: Any, n: int, what: str) -> np.ndarray:
    w = np.ascontiguousarray(np.asarray(a if a is not None else np.zeros(0)), dtype=np.float64)
    w = w.reshape(-1)
    if w.size != n:
        raise InvalidInput(f"{what}: {w.size} values for {n} elements")
    return w


# ---- data -------------------------------------------------------------------------


@dataclass
class Mesh:
    """A polygon mesh as read from a file: the CLI's input, before validation."""

    vertices: np.ndarray  #: (n, 3) float64
    face_sizes: np.ndarray  #: (m,) uint32, corners per face
    face_indices: np.ndarray  #: (sum of face_sizes,) uint32
    name: str = "input mesh"  #: the file's path; errors and report.json use it

    @property
    def faces(self) -> np.ndarray | list[np.ndarray]:
        """(m, k) array when every face has k corners, else a list of polygons."""
        s = self.face_sizes
        if s.size and np.all(s == s[0]):
            return self.face_indices.reshape(-1, int(s[0]))
        return np.split(self.face_indices, np.cumsum(s)[:-1]) if s.size else []


@dataclass
class ControlMesh:
    """A Catmull-Clark control mesh, with its creases, corners and UVs."""

    positions: np.ndarray  #: (n, 3) float64
    face_sizes: np.ndarray  #: (m,) uint32
    face_indices: np.ndarray  #: (sum of face_sizes,) uint32
    creases: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.uint32))  #: (c, 2) vertex pairs
    crease_weights: np.ndarray = field(default_factory=lambda: np.zeros(0))  #: (c,) sharpness
    corners: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint32))  #: (q,) vertices
    corner_weights: np.ndarray = field(default_factory=lambda: np.zeros(0))  #: (q,) sharpness
    #: (u, 2) float64 atlas coordinates and one index per face corner into
    #: them (parallel to face_indices); None for a mesh read from a file.
    uvs: np.ndarray | None = None
    uv_indices: np.ndarray | None = None

    def _flat(self) -> tuple[np.ndarray, ...]:
        creases = _indices(self.creases, "creases")
        if creases.size % 2:
            raise InvalidInput(f"creases: expected (c, 2) vertex pairs, got {creases.size} indices")
        corners = _indices(self.corners, "corners")
        return (
            _vertices(self.positions, "control positions"),
            _indices(self.face_sizes, "control face_sizes"),
            _indices(self.face_indices, "control face_indices"),
            creases,
            _weights(self.crease_weights, creases.size // 2, "crease_weights"),
            corners,
            _weights(self.corner_weights, corners.size, "corner_weights"),
        )

    @classmethod
    def _from_native(cls, flat: tuple, uvs: tuple | None = None) -> ControlMesh:
        p, s, i, cv, cw, qv, qw = flat
        m = cls(p.reshape(-1, 3), s, i, cv.reshape(-1, 2), cw, qv, qw)
        if uvs is not None:
            m.uvs, m.uv_indices = uvs[0].reshape(-1, 2), uvs[1]
        return m


class Conversion:
    """What :func:`convert` and :func:`fit` return."""

    def __init__(self, native: Any) -> None:
        self._native = native
        #: The control mesh (mechanical mode: its once-refined quad mesh, the
        #: one the displacement atlas is laid out on), with per-corner UVs.
        self.control: ControlMesh = ControlMesh._from_native(native.control(), native.uvs())
        faces, res, values = native.tiles()
        #: Patch (control face) of each tile.
        self.tile_faces: np.ndarray = faces
        #: Samples per side of each tile: per patch with the adaptive
        #: allocation (the default), all equal with ``displacement_allocation="uniform"``.
        self.tile_resolutions: np.ndarray = res
        ends = np.cumsum(res.astype(np.int64) ** 2)
        #: One (r, r) float32 array per tile (views into one buffer): the
        #: displacement along the limit normal, row-major in the patch's
        #: (u, v), ``tiles[k][j, i]`` at v_j, u_i.
        self.tiles: list[np.ndarray] = [
            values[e - r * r : e].reshape(r, r) for e, r in zip(ends.tolist(), res.tolist())
        ]
        #: Every number of report.json, keys as dotted paths
        #: (``"accuracy.limit.rms_permille"``), in the file's order.
        self.metrics: dict[str, float] = dict(native.metrics())
        #: report.json as the CLI writes it (timings differ run to run).
        self.report_json: str = native.report_json()
        #: control.obj, byte for byte the CLI's.
        self.control_obj: bytes = native.control_obj()

    @property
    def report(self) -> dict[str, Any]:
        """report.json, parsed."""
        return json.loads(self.report_json)

    def write(self, dir: str | os.PathLike[str], progress: Progress | None = None) -> list[Path]:
        """Writes the CLI's output set into ``dir`` (the same bytes as
        ``subdfit convert``, but for report.json's timings), swapped in whole;
        returns the files written."""
        return [Path(p) for p in self._native.write(os.fspath(dir), progress)]

    def __repr__(self) -> str:
        c = self.control
        return (
            f"<subdfit.Conversion: {c.face_sizes.size} faces, {len(c.positions)} vertices, "
            f"limit RMS {self.metrics.get('accuracy.limit.rms_permille', float('nan')):.3f}‰>"
        )


@dataclass
class LimitPoints:
    """Limit surface position, first derivatives and unit normal per point."""

    positions: np.ndarray  #: (k, 3)
    du: np.ndarray  #: (k, 3)
    dv: np.ndarray  #: (k, 3)
    normals: np.ndarray  #: (k, 3)


# ---- functions --------------------------------------------------------------------


def _options(name: str | None, **kw: Any) -> Any:
    return _subdfit.Options(name=name, **kw)


def read(path: str | os.PathLike[str]) -> Mesh:
    """Reads a mesh file (OBJ, PLY, OFF, STL) as the CLI does; ``convert`` on
    its arrays with ``name=mesh.name`` gives the CLI's result for that file."""
    p, s, i = _subdfit.read(os.fspath(path))
    return Mesh(p.reshape(-1, 3), s, i, os.fspath(path))


def read_control(path: str | os.PathLike[str]) -> ControlMesh:
    """Reads a control mesh (OBJ with OpenSubdiv's ``t crease`` / ``t corner`` tags)."""
    return ControlMesh._from_native(_subdfit.read_control(os.fspath(path)))


def _mesh_args(vertices: Any, faces: Any, face_sizes: Any, name: str | None) -> tuple:
    if isinstance(vertices, Mesh):
        if faces is not None:
            raise InvalidInput("faces: not expected with a Mesh (it has its faces)")
        m = vertices
        return (_vertices(m.vertices), *_faces(m.face_indices, m.face_sizes)), name or m.name
    if faces is None:
        raise InvalidInput("faces: missing (an (m, 3) integer array or a list of polygons)")
    return (_vertices(vertices), *_faces(faces, face_sizes)), name


def convert(
    vertices: Any,
    faces: Any = None,
    *,
    face_sizes: Any = None,
    tolerance: float = DEFAULT_TOLERANCE,
    mode: str = "auto",
    max_error: float | None = None,
    faces_target: int = 0,
    fit: str = "point",
    displacement_res: int = 0,
    m_fitmap: bool = True,
    tessellation: int = 0,
    proxy: str = "auto",
    layout: str = "greedy",
    displacement_samples: int = 0,
    threads: int = 0,
    name: str | None = None,
    progress: Progress | None = None,
    exact_metrics: bool = False,
    displacement_allocation: str = "adaptive",
    displacement_reconstruction: str = "bilinear",
) -> Conversion:
    """Dense mesh → control mesh + displacement + metrics (``subdfit convert``).

    ``vertices``: (n, 3) floats (or a :class:`Mesh`); ``faces``: an (m, k)
    integer array, a list of polygons, or flat indices with ``face_sizes``.
    Options are the CLI's: ``tolerance`` (τ, a fraction), ``mode``
    (``"auto"``, ``"organic"``, ``"mechanical"``), ``max_error``
    (RMS bound, fraction of the diagonal: mechanical E_limit per face,
    organic RMS L, default 5e-3; ``math.inf``: natural end), ``faces_target`` (``--faces``; 0: τ decides),
    ``fit`` (``"point"``/``"sdm"``), ``displacement_res`` (0: automatic),
    ``m_fitmap`` (False: ``--no-mfitmap``), ``tessellation`` (cells per
    patch side of limit.ply / displaced.ply; 0: automatic), ``proxy``
    (``"auto"``, ``"none"`` or a triangle count, as a string), ``layout``
    (``"greedy"`` or the experimental ``"field"``), ``displacement_samples``
    (displacement samples in all; 0: the input's vertex count),
    ``displacement_allocation`` (``"adaptive"``: per-patch resolution
    under that total, the default; ``"uniform"``: the same grid on every
    patch),
    ``displacement_reconstruction`` (``"bilinear"``: the maps hold samples,
    read bilinearly, the default; ``"bspline"``: they hold coefficients of
    the uniform bicubic B-spline, read with Blender/Cycles' "Cubic"
    interpolation; docs/handoff.md says what each host must do),
    ``threads`` (0: all cores), ``exact_metrics`` (``--exact-metrics``:
    measure every point; by default the displaced surface's directions are
    drawn at 100 000 points, the limit surface's and the projectability at
    300 000, and the report gives each figure's 95 % confidence interval).
    ``name`` names the input in errors and report.json (the CLI uses the
    path). Raises :class:`InvalidInput` (with the CLI's message),
    :class:`Cancelled` or ``KeyboardInterrupt``.
    """
    mesh, name = _mesh_args(vertices, faces, face_sizes, name)
    o = _options(name, tolerance=tolerance, mode=mode, max_error=max_error,
                 faces_target=faces_target, fit=fit, displacement_res=displacement_res,
                 m_fitmap=m_fitmap, tessellation=tessellation, proxy=proxy, layout=layout,
                 displacement_samples=displacement_samples, threads=threads,
                 exact_metrics=exact_metrics, displacement_allocation=displacement_allocation,
                 displacement_reconstruction=displacement_reconstruction)
    return Conversion(_subdfit.convert(mesh, o, progress))


def convert_file(path: str | os.PathLike[str], *, progress: Progress | None = None,
                 **options: Any) -> Conversion:
    """:func:`convert` of a mesh file, read and named as the CLI does."""
    o = _options(os.fspath(path), **options)
    return Conversion(_subdfit.convert_file(os.fspath(path), o, progress))


def fit(
    vertices: Any,
    faces: Any,
    control: ControlMesh,
    *,
    face_sizes: Any = None,
    tolerance: float = DEFAULT_TOLERANCE,
    fit: str = "point",
    displacement_res: int = 0,
    threads: int = 0,
    name: str | None = None,
    progress: Progress | None = None,
) -> Conversion:
    """Fits a given control mesh to a dense mesh (``subdfit fit``)."""
    mesh, name = _mesh_args(vertices, faces, face_sizes, name)
    o = _options(name, tolerance=tolerance, fit=fit, displacement_res=displacement_res,
                 threads=threads)
    return Conversion(_subdfit.fit(mesh, _control(control)._flat(), o, progress))


def _control(control: ControlMesh | Conversion) -> ControlMesh:
    if isinstance(control, Conversion):
        return control.control
    if not isinstance(control, ControlMesh):
        raise InvalidInput(f"control: expected a subdfit.ControlMesh, got {type(control).__name__}")
    return control


def limit(
    control: ControlMesh | Conversion,
    locations: Any = None,
    *,
    backend: str = "osd",
) -> LimitPoints:
    """Catmull-Clark limit surface of ``control`` (``subdfit limit``).

    Without ``locations``: at every control vertex, in order. Else
    ``locations`` is a (k, 3) array of ``(face, u, v)`` rows (on a quad
    (v0 v1 v2 v3), (0, 0) is at v0 and (1, 0) at v1: OpenSubdiv's
    convention). ``backend``: ``"osd"`` (OpenSubdiv) or ``"rust"`` (the
    exact pure-Rust evaluator).
    """
    flat = _control(control)._flat()
    faces = u = v = None
    if locations is not None:
        loc = np.asarray(locations, dtype=np.float64)
        if loc.ndim != 2 or loc.shape[1] != 3:
            raise InvalidInput(f"locations: expected a (k, 3) array of (face, u, v), got shape {loc.shape}")
        if not np.all(np.isfinite(loc)):
            raise InvalidInput("locations: non-finite value")
        f = loc[:, 0]
        if np.any(f != np.round(f)):
            raise InvalidInput("locations: face numbers must be integers")
        faces = _indices(f.astype(np.int64), "locations (faces)")
        u, v = np.ascontiguousarray(loc[:, 1]), np.ascontiguousarray(loc[:, 2])
    out = _subdfit.limit(flat, faces, u, v, backend).reshape(-1, 4, 3)
    return LimitPoints(out[:, 0], out[:, 1], out[:, 2], out[:, 3])


def batch(
    inputs: Iterable[str | os.PathLike[str]],
    out_root: str | os.PathLike[str],
    *,
    jobs: int = 1,
    force: bool = False,
    **options: Any,
) -> list[dict[str, Any]]:
    """``subdfit batch`` on this machine: one folder per asset under
    ``out_root``, unchanged assets skipped, ``batch.csv`` / ``batch.json``
    written; returns every asset's outcome. See :mod:`subdfit.distributed`
    for the same on a Dask cluster."""
    o = _options(None, **options)
    assets = _subdfit.batch_plan([os.fspath(i) for i in inputs], os.fspath(out_root))
    if jobs <= 1:
        records = [_subdfit.convert_asset(a, o, force) for a in assets]
    else:
        # The conversions release the GIL, so threads run them in parallel.
        with ThreadPoolExecutor(jobs) as pool:
            records = list(pool.map(lambda a: _subdfit.convert_asset(a, o, force), assets))
    _subdfit.write_summary(os.fspath(out_root), records)
    return [json.loads(r) for r in records]


def summary_table(outcomes: Sequence[dict[str, Any]]) -> str:
    """The table ``subdfit batch`` prints, for outcomes of :func:`batch`."""
    return _subdfit.summary_table([json.dumps(o) for o in outcomes])
