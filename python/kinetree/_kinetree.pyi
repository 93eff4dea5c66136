"""Type stubs of the compiled module; the documented API is in ``kinetree/__init__.py``."""

from typing import List, Optional, Tuple

import numpy as np
import numpy.typing as npt

class KinetreeError(ValueError): ...
class InputError(KinetreeError): ...
class ConfigError(KinetreeError): ...
class FileError(KinetreeError): ...
class ModelError(KinetreeError): ...
class TooLargeError(KinetreeError): ...

def discover(
    tracks: npt.NDArray[np.float64],
    noise_sigma: Optional[float] = None,
    config_toml: Optional[str] = None,
    config_json: Optional[str] = None,
    max_memory_gib: Optional[float] = None,
) -> str: ...
def model_json(text: str) -> str: ...
def export_model(text: str, format: str) -> str: ...
def observe(
    model_text: str,
    tracks: npt.NDArray[np.float64],
    smooth: bool = False,
    unexplained_factor: float = 3.0,
) -> Tuple[
    List[str],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    List[int],
    float,
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
]: ...
def simulate(
    mechanism: str = "paper-arm",
    seed: int = 0,
    joints: int = 3,
    tree: bool = False,
    prismatic_fraction: float = 0.3,
    spherical_fraction: float = 0.0,
    noise_sigma: float = 0.001,
    dropout: float = 0.0,
    frames: Optional[int] = None,
    points: Optional[int] = None,
    soft_tissue: Optional[float] = None,
) -> Tuple[npt.NDArray[np.float64], Optional[str]]: ...
def read_tracks(
    path: str,
    tracks_key: Optional[str] = None,
    visibility_key: Optional[str] = None,
    occluded_key: Optional[str] = None,
    max_memory_gib: float = 8.0,
) -> Tuple[npt.NDArray[np.float64], Optional[List[str]]]: ...
def view_html(
    model_text: str,
    tracks: npt.NDArray[np.float64],
    title: str,
    max_samples: int = 2000000,
    fps: Optional[float] = None,
) -> str: ...
def version() -> str: ...
