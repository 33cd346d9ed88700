"""The LaFAN1 corpus (Harvey et al. 2020) and its official preprocessing.

Reads the original BVH files from the official zip (or any directory of them), caches
the parsed clips on disk, and cuts windows exactly as the Ubisoft La Forge extractor
does (github.com/ubisoft/ubisoft-laforge-animation-dataset, ``lafan1/extract.py``):
strict sliding windows, foot contacts from FK of
the raw window, XZ-centering of the root, rotation about +Y so the hips face +X at the
last past frame (9), float64 throughout.

LaFAN1 is CC BY-NC-ND 4.0 (Ubisoft La Forge); cite Harvey et al., "Robust Motion
In-betweening", SIGGRAPH 2020.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from bezmotion.data.bvh import parse_bvh
from bezmotion.data.cache import cached_arrays, fingerprint
from bezmotion.data.corpus import MotionClips, check_split, clip_starts, concat_frames, no_source_key
from bezmotion.data.windows import center_xz, face_forward_at_frame, foot_contacts, sliding_window_starts
from bezmotion.geometry.skeleton import Skeleton, forward_kinematics

JOINT_NAMES: tuple[str, ...] = (
    "Hips", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToe", "RightUpLeg", "RightLeg", "RightFoot",
    "RightToe", "Spine", "Spine1", "Spine2", "Neck", "Head", "LeftShoulder", "LeftArm",
    "LeftForeArm", "LeftHand", "RightShoulder", "RightArm", "RightForeArm", "RightHand",
)  # fmt: skip
PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 12, 11, 14, 15, 16, 11, 18, 19, 20)
TRAIN_SUBJECTS: tuple[int, ...] = (1, 2, 3, 4)
TEST_SUBJECTS: tuple[int, ...] = (5,)
N_PAST = 10  # past context frames; facing is normalised at frame N_PAST - 1
LEFT_FOOT: tuple[int, int] = (3, 4)
RIGHT_FOOT: tuple[int, int] = (7, 8)
CONTACT_THRESHOLD = 0.02  # cm² per frame, on the squared displacement
FPS = 30
_FORMAT_VERSION = 1  # bump when the cached arrays change meaning


@dataclasses.dataclass(frozen=True)
class Lafan1Corpus:
    """All parsed LaFAN1 clips, concatenated along time; a :class:`~bezmotion.data.corpus.Corpus`.

    Split: subjects 1–4 train, subject 5 validates (the official benchmark's test set).
    Reference skeleton: the offsets of the first training file (files differ only in the
    root's OFFSET line, which the animated root replaces, and by ≤ 3.3e-5 cm elsewhere).

    Attributes:
      sequences: sequence name per file (``"walk4"``), sorted by file name.
      subjects: actor number per file (``subject5`` → 5).
      starts: ``(files + 1,)`` frame index where each file starts; file ``i`` is
        ``starts[i]:starts[i+1]``.
      offsets: ``(files, 22, 3)`` each file's OFFSET lines (they differ by ~1e-5 cm).
      quat_local: ``(frames, 22, 4)`` local rotations, continuity-fixed per file.
      root_pos: ``(frames, 3)`` root position (cm).
      cache_inputs: the files the corpus was read from (hashed into cache keys).
    """

    sequences: tuple[str, ...]
    subjects: tuple[int, ...]
    starts: np.ndarray
    offsets: np.ndarray
    quat_local: np.ndarray
    root_pos: np.ndarray
    cache_inputs: tuple[Path, ...] = ()

    name: ClassVar[str] = "lafan1"
    characteristic_map: ClassVar[str] = "lafan1"
    end_sites: ClassVar[tuple] = ()
    fps: ClassVar[float] = float(FPS)

    def __len__(self) -> int:
        return len(self.sequences)

    @property
    def num_files(self) -> int:
        return len(self.sequences)

    @property
    def clip_names(self) -> tuple[str, ...]:
        """File stems, ``"<sequence>_subject<N>"``."""
        return tuple(f"{seq}_subject{subject}" for seq, subject in zip(self.sequences, self.subjects))

    @property
    def skeleton(self) -> Skeleton:
        """The reference skeleton: the first training file's (file 0's if there is none)."""
        train = self.files_of(TRAIN_SUBJECTS)
        return self.clip_skeleton(train[0] if train else 0)

    def clip_skeleton(self, file_index: int) -> Skeleton:
        """The skeleton (offsets) of one file."""
        return Skeleton(PARENTS, JOINT_NAMES, np.asarray(self.offsets[file_index]))

    def clip(self, file_index: int) -> tuple[np.ndarray, np.ndarray]:
        """``(quat_local (T, 22, 4), root_pos (T, 3))`` of one file."""
        s, e = self.starts[file_index], self.starts[file_index + 1]
        return self.quat_local[s:e], self.root_pos[s:e]

    def labels(self, index: int) -> dict[str, str | int]:
        """``{"file", "sequence", "subject"}`` of one file."""
        return {"file": self.clip_names[index], "sequence": self.sequences[index], "subject": self.subjects[index]}

    def files_of(self, subjects: Sequence[int]) -> list[int]:
        """Indices of the files recorded by the given subjects."""
        unknown = sorted(set(subjects) - set(range(1, 6)))
        if unknown:
            raise ValueError(f"LaFAN1 subjects are 1-5, got {unknown}")
        return [i for i, s in enumerate(self.subjects) if s in subjects]

    def split(self, split: str) -> np.ndarray:
        """Files of subjects 1–4 (``"train"``) or 5 (``"validation"``), in corpus order."""
        check_split(split)
        return np.asarray(self.files_of(TRAIN_SUBJECTS if split == "train" else TEST_SUBJECTS), np.int64)

    def motion(self, indices: Sequence[int] | np.ndarray) -> MotionClips:
        """The given files, raw (no benchmark preprocessing): each file's own offsets, with
        the animated root position on joint 0."""
        quat, pos = [], []
        for f in (int(i) for i in indices):
            q, root = self.clip(f)
            p = np.broadcast_to(self.offsets[f], q.shape[:1] + self.offsets.shape[1:]).copy()
            p[:, 0] = root
            quat.append(q)
            pos.append(p)
        return MotionClips(
            PARENTS, JOINT_NAMES, concat_frames(quat, (0, 22, 4)), concat_frames(pos, (0, 22, 3)),
            clip_starts([len(q) for q in quat]), self.fps,
        )  # fmt: skip

    def source_key(self, **params) -> str:
        """:func:`~bezmotion.data.cache.fingerprint` of the zip or folder read, with ``params``."""
        if not self.cache_inputs:
            raise no_source_key(self.name)
        return fingerprint(*self.cache_inputs, **params)


def _split_file_name(name: str) -> tuple[str, int]:
    stem = Path(name).stem
    seq, _, subject = stem.rpartition("_")
    if not seq or not subject.startswith("subject") or not subject[7:].isdigit():
        raise ValueError(f"{name}: LaFAN1 file names look like '<sequence>_subject<N>.bvh'")
    return seq, int(subject[7:])


def _bvh_sources(source: Path) -> list[tuple[str, Callable[[], str]]]:
    """(file name, text loader) for every ``.bvh`` in a zip or directory, sorted by name."""
    if source.is_dir():
        files = sorted(source.glob("*.bvh"))
        return [(p.name, functools.partial(_read_text, p)) for p in files]
    if zipfile.is_zipfile(source):
        with zipfile.ZipFile(source) as zf:
            members = sorted((m for m in zf.namelist() if m.lower().endswith(".bvh")), key=lambda m: Path(m).name)
        return [(Path(m).name, functools.partial(_read_zip_member, source, m)) for m in members]
    raise ValueError(f"{source}: expected the LaFAN1 zip or a directory of its .bvh files")


def _read_text(path: Path) -> str:
    return path.read_bytes().decode("utf-8", errors="strict")


def _read_zip_member(zip_path: Path, member: str) -> str:
    with zipfile.ZipFile(zip_path) as zf:
        return zf.read(member).decode("utf-8", errors="strict")


def _parse_corpus(source: Path) -> dict[str, np.ndarray]:
    entries = _bvh_sources(source)
    if not entries:
        raise ValueError(f"{source}: no .bvh files found")
    sequences, subjects, offsets, quats, roots, starts = [], [], [], [], [], [0]
    for name, load in tqdm(entries, desc="parsing LaFAN1", unit="file", leave=False):
        seq, subject = _split_file_name(name)
        motion = parse_bvh(load(), f"{source}:{name}")
        if motion.skeleton.names != JOINT_NAMES or motion.skeleton.parents != PARENTS:
            raise ValueError(f"{source}:{name}: not the LaFAN1 hierarchy (joints {motion.skeleton.names})")
        sequences.append(seq)
        subjects.append(subject)
        offsets.append(np.asarray(motion.skeleton.offsets))
        quats.append(motion.quat_local)
        roots.append(motion.root_pos)
        starts.append(starts[-1] + motion.num_frames)
    return {
        "sequences": np.asarray(sequences),
        "subjects": np.asarray(subjects, np.int64),
        "starts": np.asarray(starts, np.int64),
        "offsets": np.stack(offsets),
        "quat_local": np.concatenate(quats),
        "root_pos": np.concatenate(roots),
    }


def load_lafan1(source: str | os.PathLike, *, use_cache: bool = True) -> Lafan1Corpus:
    """Parse every LaFAN1 BVH in ``source`` (the official zip or a directory), cached on disk.

    The first call parses (a few seconds for the 27-file subset); later calls with the
    same archive bytes load the cache.
    """
    source = Path(source)
    if not source.exists():
        raise FileNotFoundError(f"LaFAN1 source {source} does not exist")
    key = fingerprint(source, corpus="lafan1", version=_FORMAT_VERSION)
    arrays = cached_arrays("lafan1", key, lambda: _parse_corpus(source), use_cache=use_cache)
    return Lafan1Corpus(
        sequences=tuple(str(s) for s in arrays["sequences"]),
        subjects=tuple(int(s) for s in arrays["subjects"]),
        starts=arrays["starts"],
        offsets=arrays["offsets"],
        quat_local=arrays["quat_local"],
        root_pos=arrays["root_pos"],
        cache_inputs=(source,),
    )


@dataclasses.dataclass(frozen=True)
class Lafan1Windows:
    """Preprocessed windows (float64).

    Attributes:
      quat_local: ``(windows, frames, 22, 4)`` local rotations, facing-normalised.
      root_pos: ``(windows, frames, 3)`` root positions, XZ-centred and rotated (cm).
      offsets: ``(windows, 22, 3)`` the skeleton offsets of each window's file.
      contacts_left, contacts_right: ``(windows, frames, 2)`` foot contacts of the
        (foot, toe) joints, computed before centering/rotation.
      file_index, start_frame: ``(windows,)`` where each window comes from.
    """

    quat_local: np.ndarray
    root_pos: np.ndarray
    offsets: np.ndarray
    contacts_left: np.ndarray
    contacts_right: np.ndarray
    file_index: np.ndarray
    start_frame: np.ndarray

    @property
    def num_windows(self) -> int:
        return self.quat_local.shape[0]

    def fk(self, offsets: np.ndarray | None = None) -> tuple[jax.Array, jax.Array]:
        """Global ``(quat, pos)`` of every window frame, with each window's own offsets or
        one shared ``(22, 3)`` ``offsets`` array. Call inside ``jax.enable_x64(True)`` for float64."""
        offs = self.offsets[:, None] if offsets is None else offsets
        pos_local = jnp.broadcast_to(jnp.asarray(offs), self.root_pos.shape[:2] + (22, 3))
        return forward_kinematics(PARENTS, jnp.asarray(self.quat_local), pos_local, root_pos=jnp.asarray(self.root_pos))


@jax.jit
def _preprocess(quat_local, root_pos, offsets):
    """Official per-window steps: contacts on the raw window, XZ-centering, facing at frame 9."""
    pos_local = jnp.broadcast_to(offsets[:, None], root_pos.shape[:2] + offsets.shape[1:])
    _, pos_global = forward_kinematics(PARENTS, quat_local, pos_local, root_pos=root_pos)
    contacts_left = foot_contacts(pos_global, LEFT_FOOT, CONTACT_THRESHOLD)
    contacts_right = foot_contacts(pos_global, RIGHT_FOOT, CONTACT_THRESHOLD)
    root_pos = center_xz(root_pos)
    quat_local, root_pos = face_forward_at_frame(quat_local, root_pos, N_PAST - 1)
    return quat_local, root_pos, contacts_left, contacts_right


def lafan1_windows(corpus: Lafan1Corpus, subjects: Sequence[int], window: int, offset: int) -> Lafan1Windows:
    """Cut and preprocess windows from the given subjects' files (official protocol).

    Training statistics use ``window=50, offset=20`` on subjects 1–4; the benchmark test
    set is ``window=65, offset=40`` on subject 5.
    """
    if window <= N_PAST:
        raise ValueError(f"window must exceed the {N_PAST} past frames, got {window}")
    files, starts = [], []
    for f in corpus.files_of(subjects):
        n = corpus.starts[f + 1] - corpus.starts[f]
        s = sliding_window_starts(int(n), window, offset)
        files.append(np.full(len(s), f))
        starts.append(s)
    file_index = np.concatenate(files) if files else np.zeros(0, np.int64)
    start_frame = np.concatenate(starts) if starts else np.zeros(0, np.int64)
    if file_index.size == 0:
        raise ValueError(f"no LaFAN1 windows of {window} frames for subjects {list(subjects)}")
    frame_idx = corpus.starts[file_index][:, None] + start_frame[:, None] + np.arange(window)
    offsets = corpus.offsets[file_index]
    with jax.enable_x64(True):
        q, r, cl, cr = _preprocess(
            jnp.asarray(corpus.quat_local[frame_idx]), jnp.asarray(corpus.root_pos[frame_idx]), jnp.asarray(offsets)
        )
        q, r, cl, cr = (np.asarray(a) for a in (q, r, cl, cr))
    return Lafan1Windows(q, r, offsets, cl, cr, file_index, start_frame)


@dataclasses.dataclass(frozen=True)
class Lafan1Statistics:
    """Training statistics of the official protocol.

    Attributes:
      x_mean, x_std: ``(66,)`` mean and population std of the 22×3 global positions over
        all (window, frame) pairs of the training windows (cm).
      offsets: ``(22, 3)`` the offsets of the first training window, used as the constant
        skeleton for every benchmark FK (as the official evaluator does).
    """

    x_mean: np.ndarray
    x_std: np.ndarray
    offsets: np.ndarray


def lafan1_statistics(corpus: Lafan1Corpus, subjects: Sequence[int] = TRAIN_SUBJECTS) -> Lafan1Statistics:
    """Official training statistics: windows of 50 frames, offset 20, on subjects 1–4."""
    train = lafan1_windows(corpus, subjects, window=50, offset=20)
    with jax.enable_x64(True):
        _, pos = train.fk()
        flat = np.asarray(pos).reshape(-1, 66)
    return Lafan1Statistics(flat.mean(axis=0), flat.std(axis=0), train.offsets[0])
