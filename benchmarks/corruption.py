"""Benchmark: what a damaged checkpoint or saved model does — resumed from, refused, or used.

    python benchmarks/corruption.py --out corruption.json

Checkpoints: a tiny BMM trains on the bundled clip with the project's training loop
(:func:`~bezmotion.training.run_training`, checkpoints every ``--checkpoint-every`` steps,
three kept). In a copy of the run folder the latest checkpoint's largest data file (an
orbax ``d/`` file) is damaged — 64 bytes flipped, cut to half, deleted, or emptied — and
the run resumes to ``--steps`` more. Each outcome is one of

- ``"resumed_previous"``: a warning named the damaged checkpoint and the run went on from
  the one before it, to a finite state;
- ``"stopped"``: a one-line ``ValueError`` (``"flip_every"`` damages every checkpoint, so
  there is none to go back to: this is its expected outcome);
- ``"nan"``: the run ended with NaN or inf in its state;
- ``"silent"``: it trained on from the damaged checkpoint without a word;
- ``"crashed"``: another exception (an orbax or TensorStore traceback).

Models: a tiny BMM (:func:`~bezmotion.bmm.sampling.save_model`) and a tiny learned IK
(:func:`~bezmotion.ik.protores.save_ik_model`) are saved; single bits are flipped one at a
time at ``--flips`` positions per model, spread over every file of the folder (two per file
at least, the rest in the weight data files), and the folder is loaded by path. An
exception is a detection; loading with changed weights is a miss (``undetected``). The same
flips loaded with ``verify=False`` show what the checksums add.

Writes ``{"checkpoint": {"flip", "truncate", "delete", "zero", "flip_every"},
"model_bit_flips": {"tried", "detected", "undetected", …}, "details": …, "machine": …}``.
"""

from __future__ import annotations

import collections
import shutil
import sys
import tempfile
import warnings
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np

from _timing import machine_info, report
from bezmotion._src.options import option, options, parse_options
from bezmotion.assets import BUNDLED_IK, DEMO_CLIP
from bezmotion.bmm.denoiser import BMMConfig, init_denoiser
from bezmotion.bmm.features import FeatureStats
from bezmotion.bmm.sampling import BezierMotionModel, load_model, save_model
from bezmotion.bmm.train import BMMTrainConfig, CurveArrays, init_bmm_train_state, make_bmm_train_step
from bezmotion.data.bvh import read_bvh
from bezmotion.data.corpus import MotionClips
from bezmotion.data.curves import build_curve_dataset
from bezmotion.ik.protores import ProtoResConfig, ProtoResModel, init_protores, load_ik_model, save_ik_model
from bezmotion.training import CheckpointStore, compile_train_step, run_training

TINY = BMMConfig.cpu(width=32, ff_width=64, num_heads=2, num_layers=1, dropout=0.0)
DAMAGES = ("flip", "truncate", "delete", "zero")


@options
class Options:
    steps: int = option(6, help="training steps before the damage (and as many after; default 6)")
    checkpoint_every: int = option(2, help="checkpoint period in steps (default 2; three kept)")
    flips: int = option(120, help="single-bit flips per saved model (default 120)")
    seed: int = option(0, help="where the bits are flipped")
    out: str | None = option(None, help="write the result as JSON to this file (atomically)")

    def __post_init__(self):
        if self.checkpoint_every < 1 or self.steps < 2 * self.checkpoint_every:
            raise ValueError(f"--steps {self.steps} must hold two checkpoints of --checkpoint-every {self.checkpoint_every} (one to go back to)")


# ------------------------------------------------------------------------ checkpoints


def data_file(folder: Path) -> Path:
    """The largest array data file (orbax's ``d/`` folders) under ``folder``."""
    return max((p for p in folder.rglob("*") if p.is_file() and p.parent.name == "d"), key=lambda p: p.stat().st_size)


def damage(path: Path, how: str) -> None:
    data = bytearray(path.read_bytes())
    if how == "flip":
        start = len(data) // 3
        for i in range(start, min(start + 64, len(data))):
            data[i] ^= 0xFF
        path.write_bytes(bytes(data))
    elif how == "truncate":
        path.write_bytes(bytes(data[: len(data) // 2]))
    elif how == "zero":
        path.write_bytes(b"")
    elif how == "delete":
        path.unlink()


def finite(tree) -> bool:
    return all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(tree) if jnp.issubdtype(x.dtype, jnp.inexact))


def resume(kit, run: Path, damaged: int, previous: int, total: int) -> tuple[str, str]:
    """Resume ``run`` (its checkpoint ``damaged`` damaged) to ``total`` steps; ``(outcome, what it said)``."""
    store = CheckpointStore(run / "checkpoints")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                state, _ = run_training(
                    kit.step, kit.state0, kit.data, num_steps=total, store=store, checkpoint_every=kit.every, progress=False
                )
            except ValueError as error:
                return ("stopped" if "\n" not in str(error) else "crashed"), str(error)
            except Exception as error:  # what the damage made orbax or TensorStore raise
                return "crashed", f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"
        said = " | ".join(str(w.message) for w in caught if "checkpoint" in str(w.message))
        if not finite(state):
            return "nan", said
        if f"checkpoint {damaged} (" in said and f"restored checkpoint {previous} instead" in said:
            return "resumed_previous", said
        return "silent", said
    finally:
        store.close()


def checkpoint_outcomes(args, workdir: Path) -> tuple[dict, dict]:
    dataset = build_curve_dataset(MotionClips.from_bvh([read_bvh(DEMO_CLIP)]), "bandai_namco", window=31, offset=1, progress=False)
    train = BMMTrainConfig(batch_size=8, learning_rate=1e-3, ema_decay=0.9)
    graphdef, state0 = init_bmm_train_state(TINY, train, key=jax.random.key(0))
    step = compile_train_step(make_bmm_train_step(graphdef, TINY, train, FeatureStats.from_dataset(dataset)), num_seeds=None)
    kit = SimpleNamespace(step=step, state0=state0, data=CurveArrays.from_dataset(dataset), every=args.checkpoint_every)
    pristine = workdir / "pristine"
    store = CheckpointStore(pristine / "checkpoints", max_to_keep=3)
    run_training(step, state0, kit.data, num_steps=args.steps, store=store, checkpoint_every=args.checkpoint_every, progress=False)
    latest = store.latest_step()
    kept = store.steps()
    store.close()
    outcomes, details = {}, {"checkpoints_kept": kept, "damaged_step": latest}
    for how in (*DAMAGES, "flip_every"):
        run = workdir / how
        shutil.copytree(pristine, run)
        targets = [data_file(run / "checkpoints" / str(s)) for s in (kept if how == "flip_every" else [latest])]
        details.setdefault("damaged_files", {})[how] = [t.relative_to(run / "checkpoints").as_posix() for t in targets]
        for target in targets:
            damage(target, "flip" if how == "flip_every" else how)
        outcomes[how], details[how] = resume(kit, run, latest, kept[-2], 2 * args.steps)
    return outcomes, details


# ------------------------------------------------------------------------------ models


def saved_models(workdir: Path) -> dict:
    """``{kind: (folder, loader, reference params)}`` of a tiny BMM and a tiny learned IK."""
    graphdef, params = init_denoiser(TINY, key=jax.random.key(1))
    j = TINY.num_joints
    bmm = BezierMotionModel(params, FeatureStats(jnp.zeros((j, 12)), jnp.ones((j, 12))), graphdef, TINY)
    save_model(workdir / "bmm", bmm)
    character = load_ik_model(BUNDLED_IK).character
    config = ProtoResConfig.tiny(character.num_joints)
    ik_graphdef, ik_params = init_protores(config, key=jax.random.key(2))
    save_ik_model(workdir / "ik", ProtoResModel(ik_params, character, ik_graphdef, config))
    return {
        "bmm": (workdir / "bmm", load_model, {"params": bmm.params, "stats": bmm.stats}),
        "ik": (workdir / "ik", load_ik_model, {"params": ik_params}),
    }


def flip_positions(folder: Path, count: int, rng: np.random.Generator) -> list[tuple[Path, int]]:
    """``count`` (file, bit) pairs: two per file at least, the rest spread over the data files by size."""
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    picks = [(p, int(rng.integers(8 * p.stat().st_size))) for p in files for _ in range(2) if p.stat().st_size]
    data = [p for p in files if p.parent.name == "d" and p.stat().st_size]
    sizes = np.asarray([p.stat().st_size for p in data], np.float64)
    for i in rng.choice(len(data), size=max(count - len(picks), 0), p=sizes / sizes.sum()):
        picks.append((data[i], int(rng.integers(8 * data[i].stat().st_size))))
    return picks


def flip(path: Path, bit: int) -> None:
    data = bytearray(path.read_bytes())
    data[bit // 8] ^= 1 << (bit % 8)
    path.write_bytes(bytes(data))


def loaded_params(model) -> dict:
    return {"params": model.params, "stats": model.stats} if hasattr(model, "stats") else {"params": model.params}


def same(a, b) -> bool:
    return all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def model_flips(args, workdir: Path) -> tuple[dict, dict]:
    rng = np.random.default_rng(args.seed)
    totals = {verify: collections.Counter() for verify in (True, False)}
    per_file = collections.defaultdict(collections.Counter)
    errors = collections.Counter()
    for kind, (folder, load, reference) in saved_models(workdir).items():
        for path, bit in flip_positions(folder, args.flips, rng):
            flip(path, bit)
            for verify in (True, False):
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")  # verify=False warns every time
                        model = load(folder, verify=verify)
                except Exception as error:  # every refusal counts, whatever its kind
                    outcome = "detected"
                    if verify:
                        errors[type(error).__name__] += 1
                else:
                    outcome = "unchanged" if same(loaded_params(model), reference) else "undetected"
                totals[verify]["tried"] += 1
                totals[verify][outcome] += 1
                if verify:
                    per_file[f"{kind}/{path.relative_to(folder).as_posix()}"][outcome] += 1
            flip(path, bit)  # back as saved for the next flip
    verified, unverified = ({k: t[k] for k in ("tried", "detected", "undetected", "unchanged")} for t in (totals[True], totals[False]))
    details = {"errors": dict(errors), "per_file": {k: dict(v) for k, v in sorted(per_file.items())}, "unverified": unverified}
    return verified, details


def main(argv: list[str] | None = None) -> dict:
    args = parse_options(Options, argv, description=__doc__)
    with tempfile.TemporaryDirectory(prefix="bezmotion-corruption-") as tmp:
        workdir = Path(tmp)
        (workdir / "models").mkdir()
        checkpoint, checkpoint_details = checkpoint_outcomes(args, workdir)
        flips, flip_details = model_flips(args, workdir / "models")
    result = {
        "benchmark": "corruption",
        "checkpoint": checkpoint,
        "model_bit_flips": flips,
        "details": {"checkpoint": checkpoint_details, "model_bit_flips": flip_details},
        "settings": {"steps": args.steps, "checkpoint_every": args.checkpoint_every, "flips_per_model": args.flips, "seed": args.seed},
        "machine": machine_info(),
    }
    return report(result, {"checkpoint": checkpoint, "model_bit_flips": flips, "unverified_loads": flip_details["unverified"]}, args.out)


if __name__ == "__main__":
    main(sys.argv[1:])
