"""RGB-D sequences in the TUM RGB-D dataset layout (readable by the TUM benchmark tools).

Layout of a dataset folder ``root``::

    rgb.txt, depth.txt          index files: '# ...' header, then 'timestamp filename' lines
    rgb/<stamp>.png             8-bit colour (RGB content, stored by OpenCV as BGR PNG)
    depth/<stamp>.png           16-bit depth, value = round(depth_m * 5000), 0 = invalid (max 13.107 m)
    groundtruth.txt             optional TUM trajectory of the camera (see :mod:`simnav.io.tum`)
    camera.yaml                 simnav: width, height, fx, fy, cx, cy (pixels), depth_scale, T_base_camera
    segmentation.txt, segmentation/<stamp>.png   simnav, simulation only: uint16 body id + 1, 0 = nothing
    motion.txt, motion/<stamp>.npz               simnav, simulation only: key 'velocity_optical',
                                                 float32 (3, H, W), m/s, expressed in the optical frame

``<stamp>`` is the time stamp in seconds with 6 decimals (``1305031102.175304``). Written trees are
deterministic byte for byte (fixed PNG compression, fixed zip entry dates, fixed YAML layout).
"""

from __future__ import annotations

import io
import logging
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from types import TracebackType
from typing import IO

import cv2
import numpy as np
import yaml

from simnav.io import MissingDataError, format_error
from simnav.io.tum import Trajectory, fmt_float, read_tum
from simnav.sensors.readings import RGBDFrame

logger = logging.getLogger(__name__)

DEPTH_SCALE = 5000.0
"""Depth PNG units per metre (TUM convention)."""
TUM_FR1_K = np.array([[517.3, 0.0, 318.6], [0.0, 516.5, 255.3], [0.0, 0.0, 1.0]])
"""Intrinsics of the TUM 'freiburg1' camera, used when a dataset has no camera.yaml."""
MOTION_KEY = "velocity_optical"
_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]  # fast, lossless
_DEPTH_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 0]  # sensor noise makes depth incompressible (< 3 % saved)
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)
_STREAMS = {
    "rgb": ("rgb.txt", "color images", "png"),
    "depth": ("depth.txt", "depth maps", "png"),
    "segmentation": ("segmentation.txt", "segmentation masks (uint16 PNG, body id + 1, 0 = nothing)", "png"),
    "motion": ("motion.txt", "pixel motion (npz: shape, pixels, velocity_optical; m/s, optical frame)", "npz"),
}


def stamp_text(stamp_s: float) -> str:
    """Time stamp as used in file names and index files: seconds with 6 decimals."""
    return fmt_float(stamp_s, 6)


# ----------------------------------------------------------------------------------------------------------
# Pixel motion files


def save_pixel_motion(path: str | Path, velocity_optical: np.ndarray) -> None:
    """Writes a pixel-motion ``.npz`` deterministically (fixed zip dates), storing only the moving pixels.

    The archive holds ``shape`` = (3, H, W), ``pixels`` (N,) int32 row-major indices of the pixels whose velocity
    is not zero, and ``velocity_optical`` (N, 3) float32 their velocities (m/s, optical frame);
    :func:`load_pixel_motion` rebuilds the dense (3, H, W) field.

    Args:
        path: destination ``.npz`` file.
        velocity_optical: (3, H, W) velocity of the observed points, optical frame, m/s.
    """
    arr = np.asarray(velocity_optical, dtype=np.float32)
    if arr.ndim != 3 or arr.shape[0] != 3:
        raise format_error(path, None, f"expected velocity_optical of shape (3, H, W), got {arr.shape}")
    flat = arr.reshape(3, -1)
    pixels = np.flatnonzero(np.any(flat != 0, axis=0)).astype(np.int32)
    entries = {"shape": np.array(arr.shape, dtype=np.int64), "pixels": pixels,
               MOTION_KEY: np.ascontiguousarray(flat[:, pixels].T)}
    with zipfile.ZipFile(path, "w") as zf:
        for key, value in entries.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, value, allow_pickle=False)
            info = zipfile.ZipInfo(f"{key}.npy", date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.create_system = 3
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue(), compress_type=zipfile.ZIP_DEFLATED, compresslevel=1)


def load_pixel_motion(path: str | Path) -> np.ndarray:
    """Reads a pixel-motion ``.npz`` file (sparse, as written by :func:`save_pixel_motion`, or a dense
    ``velocity_optical`` array).

    Args:
        path: the ``.npz`` file.

    Returns:
        (3, H, W) float32 velocity of the observed points expressed in the optical frame, m/s.

    Raises:
        MissingDataError: the file does not exist.
        DataFormatError: not an npz with a (3, H, W) motion field.
    """
    path = Path(path)
    if not path.is_file():
        raise MissingDataError(f"{path}: pixel motion file not found")
    try:
        with np.load(path, allow_pickle=False) as npz:
            if "pixels" in npz:
                shape = tuple(int(v) for v in npz["shape"])
                dense = np.zeros((shape[0], shape[1] * shape[2]), dtype=np.float32)
                dense[:, npz["pixels"]] = npz[MOTION_KEY].T
                arr = dense.reshape(shape)
            else:
                arr = npz[MOTION_KEY]
    except (KeyError, ValueError, OSError, zipfile.BadZipFile, TypeError, IndexError):
        raise format_error(path, None, f"expected an .npz file holding '{MOTION_KEY}'") from None
    if arr.ndim != 3 or arr.shape[0] != 3:
        raise format_error(path, None, f"expected '{MOTION_KEY}' of shape (3, H, W), got {arr.shape}")
    return arr.astype(np.float32, copy=False)


# ----------------------------------------------------------------------------------------------------------
# Writer


class RGBDDatasetWriter:
    """Writes RGB-D frames into a TUM RGB-D dataset folder (context manager).

    ``rgb.txt`` and ``depth.txt`` are created with their TUM headers on construction, ``segmentation.txt`` and
    ``motion.txt`` at the first frame that has them; ``camera.yaml`` is written from the first frame (size, K,
    T_base_sensor). A ground-truth trajectory can be added with ``TumWriter(root / "groundtruth.txt")``.

    Args:
        root: dataset folder (created if needed); its name is written in the index headers.
        overwrite: allow writing into a folder that already holds a dataset (index files are truncated, older
            image files that are no longer indexed are left in place).

    Raises:
        DataFormatError: ``root`` already holds ``depth.txt`` or ``rgb.txt`` and ``overwrite`` is False.
    """

    def __init__(self, root: str | Path, *, overwrite: bool = False) -> None:
        self.root = Path(root)
        existing = [name for name, *_ in _STREAMS.values() if (self.root / name).exists()]
        if existing and not overwrite:
            raise format_error(
                self.root, None, f"already holds a dataset ({', '.join(existing)}); pass overwrite=True"
            )
        self.root.mkdir(parents=True, exist_ok=True)
        self._index: dict[str, IO[str]] = {}
        self._stamps: set[str] = set()
        self._shape: tuple[int, int] | None = None
        self._K: np.ndarray | None = None
        self._open_index("rgb")
        self._open_index("depth")
        for kind in ("segmentation", "motion"):  # stale optional indexes would describe another recording
            (self.root / _STREAMS[kind][0]).unlink(missing_ok=True)

    def write_frame(self, frame: RGBDFrame) -> None:
        """Writes one frame: depth always, rgb/segmentation/motion when the frame has them.

        Args:
            frame: the frame; depth (H, W) in m (0/NaN/inf/negative = invalid, beyond 13.107 m clipped), rgb
                (H, W, 3) uint8 RGB, body_id (H, W) int with -1 = nothing, velocity_optical (3, H, W) m/s.

        Raises:
            DataFormatError: a frame with the same 6-decimal stamp was written, or shapes/intrinsics differ
                from the first frame, or an image has the wrong shape.
        """
        if not np.isfinite(frame.stamp_s):
            raise format_error(self.root, None, f"frame time stamp must be finite, got {frame.stamp_s}")
        stamp = stamp_text(frame.stamp_s)
        if not self._index:
            raise format_error(self.root, None, "write_frame() called after close()")
        if stamp in self._stamps:
            raise format_error(self.root, None, f"frame {stamp}: a frame with this stamp was already written")
        shape = self._check_frame(frame, stamp)
        self._write_camera_once(frame, shape)
        self._stamps.add(stamp)
        self._add("depth", stamp, lambda p: _write_png(p, depth_to_png(frame.depth_m), _DEPTH_PNG_PARAMS))
        if frame.rgb is not None:
            rgb = np.ascontiguousarray(frame.rgb, dtype=np.uint8)
            self._add("rgb", stamp, lambda p: _write_png(p, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)))
        if frame.body_id is not None:
            self._add("segmentation", stamp, lambda p: _write_png(p, _segmentation_png(frame.body_id)))
        if frame.velocity_optical is not None:
            self._add("motion", stamp, lambda p: save_pixel_motion(p, frame.velocity_optical))

    def close(self) -> None:
        """Closes the index files; further writes raise."""
        for f in self._index.values():
            f.close()
        self._index = {}

    def __enter__(self) -> RGBDDatasetWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _open_index(self, kind: str) -> IO[str]:
        name, title, _ = _STREAMS[kind]
        f = open(self.root / name, "w", encoding="utf-8", newline="\n")  # noqa: SIM115
        f.write(f"# {title}\n# file: '{self.root.name}'\n# timestamp filename\n")
        self._index[kind] = f
        return f

    def _add(self, kind: str, stamp: str, write: Callable[[Path], object]) -> None:
        rel = f"{kind}/{stamp}.{_STREAMS[kind][2]}"
        (self.root / kind).mkdir(exist_ok=True)
        write(self.root / rel)
        index = self._index.get(kind) or self._open_index(kind)
        index.write(f"{stamp} {rel}\n")

    def _check_frame(self, frame: RGBDFrame, stamp: str) -> tuple[int, int]:
        depth = np.asarray(frame.depth_m)
        where = f"frame {stamp}"
        if depth.ndim != 2:
            raise format_error(self.root, None, f"{where}: expected (H, W) depth, got {depth.shape}")
        h, w = depth.shape
        checks = [
            ("rgb", frame.rgb, (h, w, 3)),
            ("body_id", frame.body_id, (h, w)),
            ("velocity_optical", frame.velocity_optical, (3, h, w)),
        ]
        for name, arr, want in checks:
            if arr is not None and np.shape(arr) != want:
                got = np.shape(arr)
                raise format_error(self.root, None, f"{where}: expected {name} of shape {want}, got {got}")
        ids = None if frame.body_id is None else np.asarray(frame.body_id, dtype=np.int64)
        if ids is not None and ids.size and (ids.min() < -1 or ids.max() > 65534):
            got = f"[{ids.min()}, {ids.max()}]"
            raise format_error(self.root, None, f"{where}: body ids must lie in [-1, 65534], got {got}")
        if self._shape is not None and (h, w) != self._shape:
            first = self._shape
            raise format_error(self.root, None, f"{where}: size {(h, w)} differs from the first {first}")
        if self._K is not None and not np.allclose(frame.K, self._K, rtol=0, atol=1e-9):
            raise format_error(self.root, None, f"{where}: K differs from the first frame's (camera.yaml)")
        return h, w

    def _write_camera_once(self, frame: RGBDFrame, shape: tuple[int, int]) -> None:
        if self._shape is not None:
            return
        self._shape, self._K = shape, np.asarray(frame.K, dtype=np.float64).copy()
        write_camera_yaml(self.root / "camera.yaml", frame.sensor, shape, self._K, frame.T_base_sensor)


def depth_to_png(depth_m: np.ndarray) -> np.ndarray:
    """(H, W) uint16 depth image: round(depth_m * 5000) clipped to 65535; 0 for invalid (<= 0, NaN, inf)."""
    d = np.asarray(depth_m, dtype=np.float64)
    ok = np.isfinite(d) & (d > 0)
    scaled = np.where(ok, np.rint(np.where(ok, d, 0.0) * DEPTH_SCALE), 0.0)
    return np.clip(scaled, 0, 65535).astype(np.uint16)


def _segmentation_png(body_id: np.ndarray) -> np.ndarray:
    return (np.asarray(body_id, dtype=np.int64) + 1).astype(np.uint16)


def _write_png(path: Path, image: np.ndarray, params: list[int] = _PNG_PARAMS) -> None:
    if not cv2.imwrite(str(path), image, params):
        raise format_error(path, None, "OpenCV could not write the PNG")


def write_camera_yaml(
    path: Path, sensor: str, shape: tuple[int, int], K: np.ndarray, T_base_camera: np.ndarray
) -> None:
    """Writes ``camera.yaml``: size and pinhole intrinsics (pixels), depth scale, optical-frame mount (m)."""
    data = {
        "sensor": str(sensor),
        "width": int(shape[1]),
        "height": int(shape[0]),
        "fx": float(K[0, 0]),
        "fy": float(K[1, 1]),
        "cx": float(K[0, 2]),
        "cy": float(K[1, 2]),
        "depth_scale": DEPTH_SCALE,
        "T_base_camera": [[float(v) for v in row] for row in np.asarray(T_base_camera, dtype=np.float64)],
    }
    header = (
        "# simnav RGB-D camera: pinhole intrinsics in pixels (optical frame: z forward, x right, y down),\n"
        "# depth PNG value = depth_m * depth_scale,\n"
        "# T_base_camera = pose of the optical frame in the robot base frame (translation in m)\n"
    )
    text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None)
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(header + text)


# ----------------------------------------------------------------------------------------------------------
# Reader


class _Index:
    """One index file: stamps (N,) s, stamp texts and file paths relative to the dataset root."""

    def __init__(self, path: Path) -> None:
        self.path = path
        stamps, self.texts, self.files = [], [], []
        with open(path, encoding="utf-8", errors="replace") as f:
            for line_no, raw in enumerate(f, start=1):
                text = raw.strip()
                if not text or text.startswith("#"):
                    continue
                tokens = text.split()
                if len(tokens) != 2:
                    n = len(tokens)
                    raise format_error(path, line_no, f"expected 'timestamp filename', got {n} fields")
                try:
                    stamps.append(float(tokens[0]))
                except ValueError:
                    got = tokens[0]
                    raise format_error(path, line_no, f"expected a numeric timestamp, got {got!r}") from None
                self.texts.append(tokens[0])
                self.files.append(tokens[1])
        self.stamps_s = np.asarray(stamps, dtype=np.float64)

    def by_microsecond(self) -> dict[int, str]:
        return {int(round(s * 1e6)): f for s, f in zip(self.stamps_s, self.files, strict=True)}


class RGBDDataset:
    """Reads a TUM RGB-D dataset folder; one item per depth image, in depth.txt order.

    Each depth image is paired with an rgb image by :meth:`associate` (``max_dt_s``); segmentation and motion
    are matched to the depth stamp exactly (to the microsecond).

    Args:
        root: dataset folder.
        max_dt_s: largest depth/rgb time difference of a pair, s; unpaired depth images get ``rgb=None``.
        require_rgb: keep only depth images that have an rgb partner.

    Attributes:
        groundtruth: ``groundtruth.txt`` as a :class:`Trajectory`, or None.
        K: (3, 3) intrinsics (camera.yaml, else the TUM freiburg1 ones).
        T_base_camera: (4, 4) mount of the optical frame (camera.yaml, else identity).

    Raises:
        MissingDataError: the folder or depth.txt does not exist.
        DataFormatError: an index file or camera.yaml is malformed.
    """

    def __init__(self, root: str | Path, *, max_dt_s: float = 0.02, require_rgb: bool = False) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise MissingDataError(f"{self.root}: RGB-D dataset folder not found")
        self._depth = self._required_index("depth.txt")
        self._rgb = self._optional_index("rgb.txt")
        seg, motion = self._optional_index("segmentation.txt"), self._optional_index("motion.txt")
        self._segmentation = seg.by_microsecond() if seg else {}
        self._motion = motion.by_microsecond() if motion else {}
        gt = self.root / "groundtruth.txt"
        self.groundtruth: Trajectory | None = read_tum(gt) if gt.is_file() else None
        self.sensor, self.K, self.depth_scale, self.T_base_camera, self.image_size = self._read_camera()
        pairs = dict(self.associate(max_dt_s))
        items = [(i, pairs.get(i)) for i in range(len(self._depth.files))]
        self._items = [(i, j) for i, j in items if j is not None or not require_rgb]

    @property
    def depth_stamps_s(self) -> np.ndarray:
        """(N,) stamps of all depth images in depth.txt, s."""
        return self._depth.stamps_s.copy()

    @property
    def rgb_stamps_s(self) -> np.ndarray:
        """(M,) stamps of all rgb images in rgb.txt, s (empty if there is none)."""
        return np.zeros(0) if self._rgb is None else self._rgb.stamps_s.copy()

    @property
    def stamps_s(self) -> np.ndarray:
        """(len(self),) stamps of the items (their depth stamps), s."""
        return self._depth.stamps_s[[i for i, _ in self._items]].copy()

    def associate(self, max_dt_s: float = 0.02) -> list[tuple[int, int]]:
        """Pairs depth and rgb images like the TUM ``associate.py`` tool.

        All (depth, rgb) pairs closer than ``max_dt_s`` are candidates; taken greedily by increasing time
        difference (ties by depth stamp, then rgb stamp), each image used at most once.

        Args:
            max_dt_s: largest time difference of a pair, s (strict).

        Returns:
            ``(depth_index, rgb_index)`` pairs into depth.txt / rgb.txt order, sorted by depth index.
        """
        rgb = self.rgb_stamps_s
        return associate_stamps(self._depth.stamps_s, rgb, max_dt_s)

    def __len__(self) -> int:
        return len(self._items)

    def __getitem__(self, i: int) -> RGBDFrame:
        """The i-th item: depth (m, float32), rgb (uint8 RGB or None), K, segmentation/motion if present."""
        di, ri = self._items[i]
        depth = self._load_depth(self.root / self._depth.files[di])
        rgb = None if ri is None or self._rgb is None else self._load_rgb(self.root / self._rgb.files[ri])
        key = int(round(self._depth.stamps_s[di] * 1e6))
        seg = self._segmentation.get(key)
        motion = self._motion.get(key)
        return RGBDFrame(
            sensor=self.sensor,
            stamp_s=float(self._depth.stamps_s[di]),
            depth_m=depth,
            rgb=rgb,
            K=self.K.copy(),
            T_base_sensor=self.T_base_camera.copy(),
            body_id=None if seg is None else self._load_segmentation(self.root / seg),
            velocity_optical=None if motion is None else load_pixel_motion(self.root / motion),
        )

    def __iter__(self) -> Iterator[RGBDFrame]:
        for i in range(len(self)):
            yield self[i]

    def _required_index(self, name: str) -> _Index:
        path = self.root / name
        if not path.is_file():
            raise MissingDataError(f"{path}: index file not found (expected a TUM RGB-D dataset folder)")
        return _Index(path)

    def _optional_index(self, name: str) -> _Index | None:
        path = self.root / name
        return _Index(path) if path.is_file() else None

    def _read_camera(self) -> tuple[str, np.ndarray, float, np.ndarray, tuple[int, int] | None]:
        path = self.root / "camera.yaml"
        if not path.is_file():
            logger.warning("%s: no camera.yaml; using the TUM freiburg1 intrinsics", self.root)
            return "camera", TUM_FR1_K.copy(), DEPTH_SCALE, np.eye(4), None
        return read_camera_yaml(path)

    def _load_image(self, path: Path, flags: int) -> np.ndarray:
        if not path.is_file():
            raise MissingDataError(f"{path}: image listed in the index not found")
        image = cv2.imread(str(path), flags)
        if image is None:
            raise format_error(path, None, "not a readable image")
        if self.image_size is not None and image.shape[:2] != self.image_size:
            raise format_error(path, None, f"image is {image.shape[:2]}, camera.yaml says {self.image_size}")
        return image

    def _load_depth(self, path: Path) -> np.ndarray:
        raw = self._load_image(path, cv2.IMREAD_UNCHANGED)
        if raw.ndim != 2 or raw.dtype != np.uint16:
            got = f"{raw.dtype} {raw.shape}"
            raise format_error(path, None, f"expected a 16-bit single-channel depth PNG, got {got}")
        return (raw.astype(np.float32) / np.float32(self.depth_scale)).astype(np.float32)

    def _load_rgb(self, path: Path) -> np.ndarray:
        return cv2.cvtColor(self._load_image(path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)

    def _load_segmentation(self, path: Path) -> np.ndarray:
        raw = self._load_image(path, cv2.IMREAD_UNCHANGED)
        if raw.ndim != 2 or raw.dtype != np.uint16:
            got = f"{raw.dtype} {raw.shape}"
            raise format_error(path, None, f"expected a 16-bit single-channel PNG, got {got}")
        return raw.astype(np.int32) - 1


def associate_stamps(first_s: np.ndarray, second_s: np.ndarray, max_dt_s: float) -> list[tuple[int, int]]:
    """Greedy one-to-one pairing of two stamp lists by smallest time difference (TUM ``associate.py``).

    Args:
        first_s: (N,) stamps, s.
        second_s: (M,) stamps, s.
        max_dt_s: pairs must be strictly closer than this, s.

    Returns:
        ``(i, j)`` index pairs sorted by i.
    """
    a, b = np.asarray(first_s, dtype=np.float64), np.asarray(second_s, dtype=np.float64)
    order = np.argsort(b, kind="stable")
    sorted_b = b[order]
    lo = np.searchsorted(sorted_b, a - max_dt_s, side="left")
    hi = np.searchsorted(sorted_b, a + max_dt_s, side="right")
    ii = np.repeat(np.arange(len(a)), hi - lo)
    jj = order[np.concatenate([np.arange(a, b) for a, b in zip(lo, hi, strict=True)] or [np.zeros(0, int)])]
    jj = jj.astype(np.int64)
    diff = np.abs(a[ii] - b[jj])
    keep = diff < max_dt_s
    ii, jj, diff = ii[keep], jj[keep], diff[keep]
    used_a, used_b, pairs = set(), set(), []
    for k in np.lexsort((b[jj], a[ii], diff)):
        i, j = int(ii[k]), int(jj[k])
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    return sorted(pairs)


def read_camera_yaml(path: Path) -> tuple[str, np.ndarray, float, np.ndarray, tuple[int, int] | None]:
    """Reads camera.yaml into ``(sensor, K (3, 3), depth_scale, T_base_camera (4, 4), (height, width))``."""
    try:
        with open(path, encoding="utf-8") as f:
            data = yaml.safe_load(f)
        fx, fy, cx, cy = (float(data[k]) for k in ("fx", "fy", "cx", "cy"))
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        T = np.asarray(data.get("T_base_camera", np.eye(4).tolist()), dtype=np.float64)
        size = (int(data["height"]), int(data["width"])) if "height" in data and "width" in data else None
        scale = float(data.get("depth_scale", DEPTH_SCALE))
    except (yaml.YAMLError, AttributeError, KeyError, TypeError, ValueError) as err:
        want = "fx, fy, cx, cy (numbers); optional width, height, depth_scale, T_base_camera"
        raise format_error(path, None, f"expected {want} ({type(err).__name__}: {err})") from None
    if T.shape != (4, 4) or scale <= 0:
        got = f"{T.shape}, {scale}"
        raise format_error(path, None, f"expected T_base_camera 4x4 and depth_scale > 0, got {got}")
    return str(data.get("sensor", "camera")), K, scale, T, size
