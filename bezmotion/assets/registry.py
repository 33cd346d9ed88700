"""Pretrained models by name: one registry of what ships, what must be retrained, and how.

    parts = load_pretrained("bandai_namco")    # BMM, learned IK, character, profile, joint limits
    bezmotion models                             # what is bundled: size, data, licence, retrain commands
    bezmotion models --write-manifest            # after retraining a bundled model (--check: verify)

Each :class:`ModelEntry` names a BMM and a learned IK trained on one skeleton, the data
they were trained on and its licence, and the commands that retrain them. Only models
whose data's licence allows shipping are bundled (in :data:`~bezmotion.assets.MODELS_DIR`,
fp16 BMM): the Bandai-Namco ones (CC BY-NC 4.0). LaFAN1 is CC BY-NC-**ND** 4.0, so models
trained on it stay out of the package: their entry points at the run folders under
``<cache>/runs`` (``~/.cache/bezmotion`` unless ``BEZMOTION_CACHE``) that their commands
write, and loading one that has not been trained there names the command.

Bundled folders are checked against :data:`MANIFEST` (``MANIFEST.json`` beside them): a
SHA-256 over every file of a folder (:func:`folder_digest`). A changed, truncated or
missing file is a :class:`ChecksumError` naming the folder and both digests, before
anything is loaded. ``tests/test_pretrained.py`` fails when the manifest is not updated
along with the files. Like every saved model, each folder also carries its own
``checksums.json`` (:func:`~bezmotion.training.checkpoint.save_model_folder`), which
:func:`~bezmotion.bmm.sampling.load_model` and :func:`~bezmotion.ik.protores.load_ik_model`
check, bundled or trained locally; a local model saved before models carried them loads
with ``verify=False``.

``bezmotion demo --bmm NAME`` and ``bezmotion inbetween --model NAME --ik-model NAME``
take these names too (:func:`resolve_folder`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Literal, NamedTuple

from bezmotion._src.checksums import DIGEST_RULE, ChecksumError, folder_digest, folder_files
from bezmotion.assets import MODELS_DIR, PROFILES_DIR
from bezmotion.bmm.sampling import BezierMotionModel, load_model
from bezmotion.data.cache import cache_dir
from bezmotion.ik.joint_limits import JointLimits
from bezmotion.ik.protocol import Character
from bezmotion.ik.protores import ProtoResModel, load_ik_model
from bezmotion._src.io import atomic_write_text
from bezmotion.pipeline.transfer import CharacterProfile

MANIFEST = "MANIFEST.json"
"""The checksum manifest's file name, in the bundled models' root folder."""
MANIFEST_FORMAT = "bezmotion.pretrained/1"

Part = Literal["bmm", "ik"]
PARTS: tuple[Part, ...] = ("bmm", "ik")

_BANDAI_DATA = (
    "the training takes (ids not a multiple of 10) of Bandai-Namco-Research-Motiondataset-2, "
    "(c) 2022 Bandai Namco Research Inc., https://github.com/BandaiNamcoResearchInc/Bandai-Namco-Research-Motiondataset"
)
_LAFAN1_DATA = "LaFAN1 subjects 1-4, (c) Ubisoft La Forge, https://github.com/ubisoft/ubisoft-laforge-animation-dataset"
_LAFAN1_LICENCE = "CC BY-NC-ND 4.0 (non-commercial, no derivatives: never shipped; train it locally)"


@dataclasses.dataclass(frozen=True)
class ModelEntry:
    """A BMM and a learned IK trained on one skeleton, by name.

    Attributes:
      name: what :func:`load_pretrained` and the command line's model options take.
      bmm, ik: the saved models' folders (POSIX paths): inside the models root
        (:data:`~bezmotion.assets.MODELS_DIR`) when ``bundled``, else inside ``<cache>/runs``.
      skeleton: the skeleton both were trained on: a profile in :data:`~bezmotion.assets.PROFILES_DIR`.
      bundled: shipped with the package (checked against :data:`MANIFEST`).
      data: the training data's attribution.
      licence: the data's licence, which the models inherit.
      commands: the commands that retrain them (the BMM's, then the IK's, and for a bundled
        IK its joint limits); they write into ``<cache>/runs``, from where a bundled model is
        copied into the package (``bezmotion/assets/README.md``) and re-checksummed.
      metrics: what they scored, in words.
      metrics_file: where the BMM's command writes its full results (not shipped).
    """

    name: str
    bmm: str
    ik: str
    skeleton: str
    bundled: bool
    data: str
    licence: str
    commands: tuple[str, ...]
    metrics: str = ""
    metrics_file: str | None = None

    def folder(self, part: Part, *, root: str | os.PathLike | None = None) -> Path:
        """The ``"bmm"`` or ``"ik"`` folder: under ``root`` (default :data:`MODELS_DIR`) when
        bundled, else under ``<cache>/runs`` (read at the call)."""
        if part not in PARTS:
            raise ValueError(f"part must be one of {PARTS}, got {part!r}")
        relative = getattr(self, part)
        if not self.bundled:
            return cache_dir() / "runs" / relative
        return Path(root if root is not None else MODELS_DIR) / relative

    def folders(self, *, root: str | os.PathLike | None = None) -> dict[Part, Path]:
        return {part: self.folder(part, root=root) for part in PARTS}

    def retrain_hint(self) -> str:
        return "retrain with: " + " && ".join(self.commands)


class NotTrained(FileNotFoundError):
    """A registered model that is not bundled and has not been trained here (the message
    names the commands that train it; :meth:`short` only what the models table adds)."""

    def __init__(self, entry: ModelEntry, part: str, folder: Path):
        self.entry, self.part, self.folder = entry, part, folder
        super().__init__(f"{self.short()}: no saved model in {folder}; {entry.retrain_hint()}")

    def short(self) -> str:
        what = "BMM" if self.part == "bmm" else "learned IK"
        return f"pretrained model {self.entry.name!r} is not bundled (its data is {self.entry.licence.split(' (')[0]}) and its {what} is not trained here"


REGISTRY: Mapping[str, ModelEntry] = {
    "bandai_namco": ModelEntry(
        name="bandai_namco",
        bmm="bmm_bandai_namco",
        ik="ik_bandai_namco",
        skeleton="bandai_namco",
        bundled=True,
        data=_BANDAI_DATA,
        licence="CC BY-NC 4.0 (non-commercial use only, attribution kept)",
        commands=(
            # One run from scratch on a CPU (its time: the model card); the model lands in
            # ~/.cache/bezmotion/runs/bmm_bandai_namco_cpu_residual/model, bundled as float16.
            "python experiments/bmm_lafan1.py --corpus bandai_namco --prediction residual --learning-rate 5e-4 --min-snr-gamma 0 "
            "--off-grid-handles 0.5 --steps 10000 --eval-every 2500 --eval-windows 500 --table6-steps 10 --handle-frames any "
            "--out results/bmm_bn_scratch_10000.json",
            "python -c \"from bezmotion.bmm.sampling import save_model, load_model; import os; save_model('bezmotion/assets/models/bmm_bandai_namco', "
            "load_model(os.path.expanduser('~/.cache/bezmotion/runs/bmm_bandai_namco_cpu_residual/model')), storage_dtype='float16')\"",
            "python experiments/train_ik.py --corpus bandai_namco",
            "python experiments/joint_limits.py --corpus bandai_namco --out bezmotion/assets/models/ik_bandai_namco/joint_limits.json",
            "bezmotion models --write-manifest",
        ),
        metrics=(
            "BMM (10,000 steps x 64 from scratch, handles off the control grid half of the time), 500 validation "
            "windows, curves before IK, 10 DDIM steps: dense six-joint error 4.12 cm (reference curves through start, end and handles: "
            "7.04 cm; 0.58x), foot skating 0.115 (reference 0.127), handles at any frame 4.27 cm (reference 7.55), handles hit "
            "exactly; learned IK, every 4th "
            "validation frame (8,617): MPJPE 0.40 cm from the six joints' positions and rotations, 1.18 cm from positions only"
        ),
        metrics_file="results/bmm_bn_scratch_10000.json",
    ),
    "lafan1": ModelEntry(
        name="lafan1",
        bmm="bmm_lafan1_paper_residual_cosine500/model",
        ik="ik_lafan1_paper/model",
        skeleton="lafan1",
        bundled=False,
        data=_LAFAN1_DATA,
        licence=_LAFAN1_LICENCE,
        commands=(
            # The paper-size models of the second GPU run (experiments/gpu_lafan1.sh, jobs paper_cosine and
            # ik_paper: 183 s and 248 s on an H200). On a 2-core CPU these steps take days: add --train-seconds
            # to spread them over sessions, or train the CPU-size model (--config cpu, job cpu_residual: 0.91x).
            "python experiments/bmm_lafan1.py --config paper --out results/bmm_lafan1_paper_cosine.json --prediction residual "
            "--min-snr-gamma 0 --off-grid-handles 0.5 --batch-size 256 --learning-rate 2e-4 --lr-schedule cosine --warmup-steps 500 "
            "--steps 12000 --eval-windows 1000 --table6-steps 10",
            "python experiments/train_ik.py --corpus lafan1 --config paper --steps 20000 --out-dir ~/.cache/bezmotion/runs/ik_lafan1_paper",
            "python experiments/joint_limits.py --corpus lafan1 --out ~/.cache/bezmotion/runs/ik_lafan1_paper/model/joint_limits.json",
        ),
        metrics=(
            "written by its commands: results/bmm_lafan1_paper_cosine.json and <cache>/runs/ik_lafan1_paper/training.json. "
            "The GPU run: 1,000 subject-5 windows, curves before IK, 10 DDIM steps: dense six-joint error 9.83 cm "
            "(reference 11.47; 0.86x), skating 0.102 (reference 0.067; 0.029 with foot lock), handles hit exactly; "
            "IK (22 M): validation MPJPE 2.33 cm from the six joints; after the exact IK, 100 windows: handles 0.056 / 0.58 cm ID / OOD (the paper: 0.89 / 1.71)"
        ),
        metrics_file="results/bmm_lafan1_paper_cosine.json",
    ),
    "lafan1_cpu": ModelEntry(
        name="lafan1_cpu",
        bmm="bmm_lafan1_cpu_residual/model",
        ik="ik_lafan1/model",
        skeleton="lafan1",
        bundled=False,
        data=_LAFAN1_DATA,
        licence=_LAFAN1_LICENCE,
        commands=(
            # The CPU-size models (2.3 M and the CPU IK), about an hour on a 2-core CPU. No wall-clock cap: a run
            # stopped by one is another model; an interrupted run goes on from its checkpoint.
            "python experiments/bmm_lafan1.py --corpus lafan1 --prediction residual --learning-rate 5e-4 --min-snr-gamma 0 "
            "--off-grid-handles 0.5 --steps 10000 --eval-every 2500 --eval-windows 300 --table6-steps 10 "
            "--handle-frames any --out results/bmm_lafan1_cpu.json",
            "python experiments/train_ik.py --corpus lafan1",
            "python experiments/joint_limits.py --corpus lafan1 --out ~/.cache/bezmotion/runs/ik_lafan1/model/joint_limits.json",
        ),
        metrics=(
            "written by its commands: results/bmm_lafan1_cpu.json and <cache>/runs/ik_lafan1/training.json. 300 subject-5 "
            "windows, curves before IK, 10 DDIM steps: dense six-joint error 10.91 cm (reference 11.70; 0.93x), skating 0.085 "
            "(0.021 with foot lock), handles hit exactly, at any frame 11.40 cm (+4.5 %); IK: validation MPJPE 2.05 cm from the "
            "six joints; after the exact IK, 1,000 windows: handles 0.0029 / 0.11 cm ID / OOD (the paper: 0.89 / 1.71)"
        ),
        metrics_file="results/bmm_lafan1_cpu.json",
    ),
}
"""Every model by name: bundled ones and those their commands train locally."""


class PretrainedParts(NamedTuple):
    """What :func:`load_pretrained` returns (:func:`bezmotion.pretrained` puts them in one model object).

    Attributes:
      bmm: the Bézier Motion Model (:func:`~bezmotion.bmm.sampling.sample_curves`).
      ik: the learned IK, the ``ik_params`` of :func:`~bezmotion.ik.protores.protores_ik_fn`.
      character: the skeleton both were trained on (``ik.character``).
      profile: that skeleton's profile, for :meth:`~bezmotion.pipeline.transfer.Transfer.between`.
      joint_limits: the IK's joint limits (``joint_limits.json``), or None.
      entry: the registry entry (data, licence, commands).
    """

    bmm: BezierMotionModel
    ik: ProtoResModel
    character: Character
    profile: CharacterProfile
    joint_limits: JointLimits | None
    entry: ModelEntry


# -------------------------------------------------------------------------- checksums


def folder_record(folder: str | os.PathLike) -> dict:
    """``{"sha256", "files", "bytes"}`` of a folder, as the manifest stores it."""
    files = folder_files(folder)
    return {"sha256": folder_digest(folder), "files": len(files), "bytes": sum(p.stat().st_size for p in files)}


def bundled_folders(root: str | os.PathLike | None = None) -> dict[str, Path]:
    """Every bundled entry's folders by their name in the manifest (their path under ``root``)."""
    out = {}
    for entry in REGISTRY.values():
        if entry.bundled:
            for part in PARTS:
                out[getattr(entry, part)] = entry.folder(part, root=root)
    return out


def manifest_path(root: str | os.PathLike | None = None) -> Path:
    return Path(root if root is not None else MODELS_DIR) / MANIFEST


def read_manifest(root: str | os.PathLike | None = None) -> dict[str, dict]:
    """``{folder name: {"sha256", "files", "bytes"}}`` from ``root``'s :data:`MANIFEST`.

    Raises:
      FileNotFoundError: no manifest there.
      ValueError: not a manifest of this format.
    """
    path = manifest_path(root)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no checksum manifest (write it with bezmotion models --write-manifest)")
    data = json.loads(path.read_text(encoding="utf-8"))
    if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT or not isinstance(data.get("folders"), dict):
        raise ValueError(f"{path}: not a {MANIFEST_FORMAT} manifest")
    return data["folders"]


def write_manifest(root: str | os.PathLike | None = None) -> Path:
    """Write :data:`MANIFEST` for every bundled folder under ``root`` (default the package's); returns its path."""
    folders = {name: folder_record(folder) for name, folder in sorted(bundled_folders(root).items())}
    path = manifest_path(root)
    atomic_write_text(path, json.dumps({"format": MANIFEST_FORMAT, "digest": DIGEST_RULE, "folders": folders}, indent=2) + "\n")
    return path


def verify_folder(folder: str | os.PathLike, *, root: str | os.PathLike | None = None) -> None:
    """Check a bundled folder against the manifest in ``root`` (default the package's).

    Raises:
      FileNotFoundError: no such folder.
      ChecksumError: not in the manifest, or its files differ (names both digests).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: bundled model folder missing; reinstall bezmotion")
    expected = read_manifest(root).get(folder.name)
    if expected is None:
        raise ChecksumError(f"{folder}: not in {manifest_path(root)}; run bezmotion models --write-manifest")
    actual = folder_record(folder)
    if actual["sha256"] != expected["sha256"]:
        raise ChecksumError(
            f"{folder}: checksum mismatch: expected sha256 {expected['sha256']}, got {actual['sha256']} "
            f"({expected.get('files')} files of {expected.get('bytes')} bytes expected, {actual['files']} of {actual['bytes']} found); "
            "the files were changed or are incomplete: reinstall bezmotion, or after retraining on purpose run "
            "bezmotion models --write-manifest"
        )


# ----------------------------------------------------------------------------- lookup


def model_names() -> list[str]:
    return list(REGISTRY)


def _known() -> str:
    return ", ".join(f"{e.name} ({'bundled' if e.bundled else 'not bundled, trained locally'})" for e in REGISTRY.values())


def get_entry(name: str) -> ModelEntry:
    """The registry entry of ``name``.

    Raises:
      ValueError: an unknown name (the message lists the known ones).
    """
    entry = REGISTRY.get(str(name))
    if entry is None:
        raise ValueError(f"unknown pretrained model {str(name)!r}; known: {_known()}")
    return entry


def model_folder(name: str, part: Part, *, root: str | os.PathLike | None = None, verify: bool = True) -> Path:
    """The checked ``"bmm"`` or ``"ik"`` folder of a registered model.

    Args:
      name: a name in :data:`REGISTRY`.
      part: which model.
      root: the bundled models' root (default :data:`MODELS_DIR`; a test's copy).
      verify: check a bundled folder against the manifest (:func:`verify_folder`).
    Raises:
      ValueError: an unknown name.
      ChecksumError: a bundled folder's files differ from the manifest.
      FileNotFoundError: a bundled folder is missing, or a local model was not trained
        (the message names the command that trains it).
    """
    entry = get_entry(name)
    folder = entry.folder(part, root=root)
    if entry.bundled:
        if verify:
            verify_folder(folder, root=root)
        elif not folder.is_dir():
            raise FileNotFoundError(f"{folder}: bundled model folder missing; reinstall bezmotion")
    elif not (folder / "config.json").is_file():
        raise NotTrained(entry, part, folder)
    return folder


def trained_for(skeleton: str | None, part: Part) -> str | None:
    """The first registered model trained on ``skeleton`` (a profile name, e.g. a recognised
    clip's preset) whose ``"bmm"`` or ``"ik"`` is here: bundled, or trained into ``<cache>/runs``
    by its commands. None when there is none (or no ``skeleton``)."""
    for entry in REGISTRY.values():
        if skeleton is None or entry.skeleton != skeleton:
            continue
        try:
            model_folder(entry.name, part, verify=False)  # raises where it is not here
        except FileNotFoundError:
            continue
        return entry.name
    return None


def resolve_folder(name_or_path: str | os.PathLike, part: Part, *, verify: bool = True) -> tuple[Path, ModelEntry | None]:
    """``(folder, entry or None)`` of a registered name (checked when ``verify``, :func:`model_folder`)
    or a saved model's folder (its own checksums are checked where it is loaded:
    :func:`~bezmotion.bmm.sampling.load_model`, :func:`~bezmotion.ik.protores.load_ik_model`)."""
    entry = REGISTRY.get(str(name_or_path))
    if entry is None:
        return Path(name_or_path), None
    return model_folder(entry.name, part, verify=verify), entry


def load_pretrained(name: str, *, root: str | os.PathLike | None = None, verify: bool = True) -> PretrainedParts:
    """A registered model's BMM, learned IK, character, profile and joint limits.

    ``bm.pretrained("bandai_namco")`` loads the bundled models (their checksums checked
    first); ``"lafan1"`` loads the ones ``bezmotion models`` says how to train.

    Args:
      name: a name in :data:`REGISTRY` (``bezmotion models`` lists them).
      root: the bundled models' root and manifest (default :data:`MODELS_DIR`).
      verify: check bundled folders against the manifest, and every model folder against
        its own checksums (``False`` loads one saved before models carried them, and warns).
    Raises:
      ValueError: an unknown name (listing the known ones), or weights holding NaN or inf.
      ChecksumError: a bundled folder differs from the manifest (naming the folder and
        the expected and actual digests), or a model folder from its own checksums (or has none).
      FileNotFoundError: a model that is not bundled has not been trained (naming the command).
    """
    entry = get_entry(name)
    folders = {part: model_folder(name, part, root=root, verify=verify) for part in PARTS}
    bmm = load_model(folders["bmm"], verify=verify)
    ik = load_ik_model(folders["ik"], verify=verify)
    limits_file = folders["ik"] / "joint_limits.json"
    limits = JointLimits.load(limits_file, ik.character) if limits_file.is_file() else None
    profile = CharacterProfile.load(PROFILES_DIR / f"{entry.skeleton}.json")
    return PretrainedParts(bmm, ik, ik.character, profile, limits, entry)


# ------------------------------------------------------------------------------ listing


def folder_bytes(folder: str | os.PathLike) -> int:
    return sum(p.stat().st_size for p in folder_files(folder))


def stored_values(folder: str | os.PathLike) -> int | None:
    """How many numbers a saved model stores (its parameters, and a BMM's 144 feature
    statistics), read from the latest checkpoint's metadata; None when unreadable."""
    steps = [p for p in Path(folder).iterdir() if p.name.isdigit() and p.is_dir()] if Path(folder).is_dir() else []
    if not steps:
        return None
    metadata = max(steps, key=lambda p: int(p.name)) / "default" / "_METADATA"
    try:
        tree = json.loads(metadata.read_text(encoding="utf-8"))["tree_metadata"]
        return sum(math.prod(v["value_metadata"]["write_shape"]) for v in tree.values())
    except (OSError, ValueError, KeyError, TypeError):
        return None


def entry_status(entry: ModelEntry, *, root: str | os.PathLike | None = None) -> tuple[str, bool]:
    """``(status in words, loadable)``."""
    try:
        for part in PARTS:
            model_folder(entry.name, part, root=root)
    except ChecksumError:
        return "bundled, CHECKSUM MISMATCH", False
    except FileNotFoundError:
        return ("bundled, MISSING" if entry.bundled else "not bundled, not trained here"), False
    return ("bundled, checksum ok" if entry.bundled else "not bundled, trained here"), True


def models_table(*, root: str | os.PathLike | None = None) -> str:
    """What ``bezmotion models`` prints: one row per entry, then each one's data, licence,
    metrics, folders and retrain commands."""
    rows = [("name", "status", "size", "BMM", "IK", "skeleton", "licence")]
    details = []
    for entry in REGISTRY.values():
        status, present = entry_status(entry, root=root)
        folders = entry.folders(root=root)
        size = values = ik_values = "-"
        if present:
            size = f"{sum(folder_bytes(f) for f in folders.values()) / 1e6:.1f} MB"
            counts = [stored_values(folders[part]) for part in PARTS]
            values, ik_values = (f"{c / 1e6:.2f} M" if c else "?" for c in counts)
        rows.append((entry.name, status, size, values, ik_values, entry.skeleton, entry.licence.split(" (")[0]))
        commands = "\n".join(f"  {'retrain:' if i == 0 else '':9}{c}" for i, c in enumerate(entry.commands))
        details.append(
            f"{entry.name}\n  data:    {entry.data}\n  licence: {entry.licence}\n  metrics: {entry.metrics}\n"
            f"  folders: {folders['bmm']}, {folders['ik']}\n{commands}"
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    table = "\n".join("  ".join(cell.ljust(w) for cell, w in zip(r, widths)).rstrip() for r in rows)
    return (
        "Pretrained models (Python: bezmotion.pretrained(NAME); commands: --model NAME, --ik-model NAME).\n"
        "BMM and IK: numbers stored (parameters; the BMM's also its 144 feature statistics).\n\n"
        f"{table}\n\n" + "\n\n".join(details)
    )


def check_manifest(root: str | os.PathLike | None = None) -> Path:
    """Check every bundled folder against the manifest (:func:`verify_folder`); returns the manifest's path."""
    for folder in bundled_folders(root).values():
        verify_folder(folder, root=root)
    return manifest_path(root)


__all__ = [
    "MANIFEST",
    "REGISTRY",
    "ChecksumError",
    "ModelEntry",
    "NotTrained",
    "PretrainedParts",
    "check_manifest",
    "folder_digest",
    "get_entry",
    "model_folder",
    "model_names",
    "models_table",
    "load_pretrained",
    "read_manifest",
    "resolve_folder",
    "trained_for",
    "verify_folder",
    "write_manifest",
]
