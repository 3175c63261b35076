# Type stubs of the native module (python/src/lib.rs). Arrays are flat and
# contiguous; `subdfit/__init__.py` gives them that form and their shapes.

from os import PathLike
from typing import Any, Callable

import numpy as np
import numpy.typing as npt

_F64 = npt.NDArray[np.float64]
_F32 = npt.NDArray[np.float32]
_U32 = npt.NDArray[np.uint32]
_Path = str | PathLike[str]
_Progress = Callable[[str, float], Any] | None
_Mesh = tuple[_F64, _U32, _U32]
_Control = tuple[_F64, _U32, _U32, _U32, _F64, _U32, _F64]

class Error(Exception):
    """Any error of subdfit."""

class InvalidInput(Error):
    """A mesh, an array or an option that cannot be used."""

class InvalidOption(InvalidInput):
    """An option out of its range; the message names the option."""

class FileError(Error):
    """A file that cannot be opened, read or written."""

class NumericalError(Error):
    """A numerical stage failed on a valid input."""

class BackendError(NumericalError):
    """A C++ backend or a solver failed."""

class InternalError(Error):
    """A bug in subdfit: please report it."""

class Cancelled(Error):
    """The progress callback returned False."""

class Options:
    def __init__(
        self,
        *,
        tolerance: float | None = None,
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
        exact_metrics: bool = False,
        displacement_allocation: str = "adaptive",
        displacement_reconstruction: str = "bilinear",
    ) -> None: ...
    @property
    def tolerance(self) -> float: ...
    @property
    def name(self) -> str: ...

class NativeConversion:
    def control(self) -> _Control: ...
    def uvs(self) -> tuple[_F64, _U32]: ...
    def tiles(self) -> tuple[_U32, _U32, _F32]: ...
    def metrics(self) -> list[tuple[str, float]]: ...
    def report_json(self) -> str: ...
    def control_obj(self) -> bytes: ...
    def write(self, dir: _Path, progress: _Progress = None) -> list[str]: ...

def read(path: _Path) -> _Mesh: ...
def read_control(path: _Path) -> _Control: ...
def convert(mesh: _Mesh, options: Options, progress: _Progress = None) -> NativeConversion: ...
def convert_file(path: _Path, options: Options, progress: _Progress = None) -> NativeConversion: ...
def fit(
    mesh: _Mesh, control: _Control, options: Options, progress: _Progress = None
) -> NativeConversion: ...
def limit(
    control: _Control, faces: _U32 | None, u: _F64 | None, v: _F64 | None, backend: str
) -> _F64: ...
def batch_plan(inputs: list[str], out_root: _Path) -> list[str]: ...
def convert_asset(
    asset: str, options: Options, force: bool = False, progress: _Progress = None
) -> str: ...
def write_summary(out_root: _Path, records: list[str]) -> list[str]: ...
def summary_table(records: list[str]) -> str: ...
def version() -> str: ...
