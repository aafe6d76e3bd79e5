"""Type stubs of the Rust extension (crates/python/src/lib.rs). Use the wrappers in
`fusiondet` instead: they convert to and from dicts and numpy arrays."""

from typing import List, Optional, Sequence, Tuple

ANNO_COLS: int

class FusiondetError(ValueError):
    """Bad input; the message names the file, line and field (or annos entry) at fault."""

def evaluate_kitti_json(
    label_dir: str,
    result_dir: str,
    split_ids: Optional[Sequence[str]] = None,
    split_file: Optional[str] = None,
    classes: Optional[Sequence[str]] = None,
    breakdown: bool = False,
    velodyne_dir: Optional[str] = None,
    calib_dir: Optional[str] = None,
    baseline_dir: Optional[str] = None,
    resamples: int = 1000,
    seed: int = 0,
    confidence: float = 0.95,
) -> Tuple[str, List[str], List[str]]: ...
def evaluate_sunrgbd_json(
    label_dir: str,
    result_dir: str,
    split_ids: Optional[Sequence[str]] = None,
    split_file: Optional[str] = None,
) -> Tuple[str, List[str]]: ...
def evaluate_annos(
    gt_names: Sequence[str],
    gt_counts: Sequence[int],
    gt_values: bytes,
    dt_names: Sequence[str],
    dt_counts: Sequence[int],
    dt_values: bytes,
    classes: Sequence[str],
) -> Tuple[bool, List[Tuple[str, int, str, float, List[float], List[float]]]]: ...
def read_label_packed(path: str) -> Tuple[List[str], bytes]: ...
def read_results_packed(path: str) -> Tuple[List[str], bytes]: ...
def read_velodyne_bytes(path: str) -> bytes: ...
def read_calib_lists(path: str) -> List[Tuple[str, List[float]]]: ...
