"""Options classes turned into command lines (:mod:`bezmotion._src.options`), and every
experiment and benchmark script's command line built from its options class."""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
import pytest

from bezmotion.bmm.denoiser import BMMConfig
from bezmotion.delta.model import DeltaConfig
from bezmotion.ik.protores import ProtoResConfig
from bezmotion._src.options import PRESET_NAMES, option, options, options_parser, parse_options, presets

REPO_ROOT = Path(__file__).resolve().parents[2]


@options
class Example:
    """Train an example.

    A second paragraph that --help leaves out."""

    KIND: ClassVar[str] = "example"
    out: str = option(help="output JSON")
    steps: int = option(100, help="training steps")
    rate: float = 1e-3
    name: str | None = None
    folder: Path = Path("runs")
    mode: Literal["fast", "exact"] = option("exact", help="how to solve")
    config: str = option("cpu", choices=presets(BMMConfig), help="model size")
    seeds: tuple[int, ...] = option((0,), help="seeds trained together")
    offset: tuple[float, float, float] = option((0.0, 25.0, 0.0), metavar=("X", "Y", "Z"), help="cm")
    overwrite: bool = True
    skip: bool | None = option(None, help="override the preset's")
    no_progress: bool = False

    def __post_init__(self):
        if self.steps < 0:
            raise ValueError(f"--steps must be non-negative, got {self.steps}")


def test_every_supported_type_parses_to_a_frozen_instance():
    args = parse_options(
        Example,
        ["--out", "o.json", "--steps", "7", "--rate", "0.5", "--name", "n", "--folder", "f", "--mode", "fast",
         "--config", "tiny", "--seeds", "1", "2", "--offset", "1", "2", "3", "--no-overwrite", "--skip", "--no-progress"],
    )  # fmt: skip
    assert args == Example(
        out="o.json", steps=7, rate=0.5, name="n", folder=Path("f"), mode="fast", config="tiny", seeds=(1, 2),
        offset=(1.0, 2.0, 3.0), overwrite=False, skip=True, no_progress=True,
    )  # fmt: skip
    with pytest.raises(dataclasses.FrozenInstanceError):
        args.steps = 1  # type: ignore[misc]


def test_defaults_come_from_the_fields():
    args = parse_options(Example, ["--out", "o.json"])
    assert args == Example(out="o.json")
    assert (args.steps, args.seeds, args.offset, args.overwrite, args.skip, args.no_progress) == (100, (0,), (0.0, 25.0, 0.0), True, None, False)
    assert isinstance(args.folder, Path) and Example.KIND == "example"


def test_help_lists_every_flag_with_its_text(capsys):
    with pytest.raises(SystemExit) as exit_:
        parse_options(Example, ["--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert "Train an example." in text and "second paragraph" not in text
    for flag in ("--out OUT", "--steps STEPS", "--mode {fast,exact}", "--config {cpu,paper,tiny}", "--seeds SEEDS [SEEDS ...]",
                 "--offset X Y Z", "--overwrite, --no-overwrite", "--skip, --no-skip", "--no-progress"):  # fmt: skip
        assert flag in text, flag
    assert "how to solve" in text and "override the preset's" in text
    assert "--kind" not in text.lower()  # a ClassVar is no option
    assert "--no-no-progress" not in text  # a no_… field is a plain switch


def test_description_defaults_to_the_class_docstring_and_can_be_given():
    assert options_parser(Example).description == "Train an example."
    assert options_parser(Example, description="Script.\n\nDetails.").description == "Script."


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "the following arguments are required: --out"),
        (["--out", "o", "--steps", "many"], "argument --steps: invalid int value: 'many'"),
        (["--out", "o", "--rate", "fast"], "argument --rate: invalid float value: 'fast'"),
        (["--out", "o", "--mode", "slow"], "argument --mode: invalid choice: 'slow' (choose from 'fast', 'exact')"),
        (["--out", "o", "--config", "huge"], "argument --config: invalid choice: 'huge' (choose from 'cpu', 'paper', 'tiny')"),
        (["--out", "o", "--offset", "1", "2"], "argument --offset: expected 3 arguments"),
        (["--out", "o", "--seeds"], "argument --seeds: expected at least one argument"),
        (["--out", "o", "--unknown"], "unrecognized arguments: --unknown"),
        (["--out", "o", "--steps", "-1"], "--steps must be non-negative, got -1"),  # the class's own check
    ],
)
def test_bad_values_exit_through_argparse_with_the_message(capsys, argv, message):
    with pytest.raises(SystemExit) as exit_:
        parse_options(Example, argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert message in err and err.startswith("usage:")


def test_unsupported_declarations_fail_when_the_class_is_declared():
    with pytest.raises(TypeError, match=r"option Bad\.values: unsupported type 'list\[int\]'"):

        @options
        class Bad:
            values: list[int] = ()

    with pytest.raises(TypeError, match=r"option Mixed\.pair: a tuple option holds one or more values of one type"):

        @options
        class Mixed:
            pair: tuple[int, str] = (1, "a")

    with pytest.raises(TypeError, match=r"option On\.no_cache: a no_… switch defaults to False, got True"):

        @options
        class On:
            no_cache: bool = True

    with pytest.raises(ValueError, match=r"an option's default must be immutable .*, got \[0\]"):
        option([0])


def test_a_script_loaded_by_path_declares_its_options(tmp_path, capsys):
    """Tests load scripts with importlib, which leaves them out of ``sys.modules``; plain
    dataclasses then fail on string annotations, options classes do not."""
    script = tmp_path / "script.py"
    script.write_text(
        "from __future__ import annotations\n"
        "from pathlib import Path\n"
        "from typing import Literal\n"
        "from bezmotion._src.options import option, options, parse_options\n\n"
        "@options\n"
        "class Options:\n"
        "    data: Path = option(help='corpus')\n"
        "    mode: Literal['a', 'b'] = 'a'\n\n"
        "def main(argv=None):\n"
        "    return parse_options(Options, argv, description=__doc__)\n"
    )
    spec = importlib.util.spec_from_file_location("_unregistered_script", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert "_unregistered_script" not in sys.modules
    assert module.main(["--data", "x", "--mode", "b"]) == module.Options(data=Path("x"), mode="b")


def test_presets_are_the_configs_classmethods_by_name():
    parents = {"parents": (-1, 0, 1, 0)}  # a 4-joint skeleton
    for config_cls, args, kwargs in ((BMMConfig, (), {}), (DeltaConfig, (), parents), (ProtoResConfig, (22,), {})):
        found = presets(config_cls)
        assert tuple(found) == PRESET_NAMES
        for name, make in found.items():
            assert make(*args, **kwargs) == getattr(config_cls, name)(*args, **kwargs)
    assert BMMConfig.tiny(prediction="residual") == BMMConfig.cpu(width=32, ff_width=64, num_heads=2, num_layers=1, prediction="residual")
    assert DeltaConfig.tiny(**parents) == DeltaConfig.cpu(width=32, num_blocks=1, num_heads=2, embedding_dim=8, **parents)
    # Fixed settings are bound into every preset; the caller's overrides still apply.
    bound = presets(DeltaConfig, input_delta="none", **parents)
    assert bound["tiny"](output_delta="last") == DeltaConfig.tiny(input_delta="none", output_delta="last", **parents)
    with pytest.raises(ValueError, match="Example defines no size preset"):
        presets(Example)


# ---------------------------------------------------------------- the real scripts

def _scripts(folder: str) -> tuple[str, ...]:
    """Every script in a folder of the repository (its helper modules, ``_*.py``, aside)."""
    return tuple(sorted(p.stem for p in (REPO_ROOT / folder).glob("*.py") if not p.name.startswith("_")))


EXPERIMENTS, BENCHMARKS = _scripts("experiments"), _scripts("benchmarks")
_SIBLINGS = ("_common", "_delta", "_timing")  # the helper modules beside the scripts


@pytest.fixture
def load_script(monkeypatch):
    """Import a script by path as Python runs it: its folder first on ``sys.path``."""
    saved = {name: sys.modules.pop(name) for name in _SIBLINGS if name in sys.modules}

    def load(folder: str, name: str):
        monkeypatch.syspath_prepend(str(REPO_ROOT / folder))
        spec = importlib.util.spec_from_file_location(f"_options_test_{name}", REPO_ROOT / folder / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    yield load
    for name in _SIBLINGS:
        sys.modules.pop(name, None)
    sys.modules.update(saved)


def _help(module, capsys) -> str:
    with pytest.raises(SystemExit) as exit_:
        module.main(["--help"])
    assert exit_.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize(("folder", "name"), [("experiments", n) for n in EXPERIMENTS] + [("benchmarks", n) for n in BENCHMARKS])
def test_every_script_answers_help_from_its_options_class(load_script, capsys, folder, name):
    module = load_script(folder, name)
    text = _help(module, capsys)
    assert text.startswith("usage:") and module.__doc__.strip().split("\n\n")[0].split()[0] in text
    for field in dataclasses.fields(module.Options):
        assert "--" + field.name.replace("_", "-") in text


# docs/reproducing.md's "Reproducing the paper numbers" commands (and the smoke tests' flags) parse.
README_COMMANDS = [
    ("experiments", "lafan1_baselines", ["--data", "../shared/data/lafan1/lafan1-subset.zip", "--out", "results/lafan1_baselines.json"]),
    ("experiments", "bezier_stride", ["--data", "../shared/data/lafan1/lafan1-subset.zip", "--out", "results/bezier_stride.json"]),
    ("benchmarks", "bezier_fit", ["--data", "../shared/data", "--out", "results/bezier_fit.json"]),
    ("experiments", "bmm_lafan1", ["--out", "results/bmm_lafan1.json"]),
    ("experiments", "bmm_lafan1", ["--corpus", "bandai_namco", "--spans", "8", "90", "--holdout-contents", "run", "--out", "r.json"]),
    ("experiments", "gap_lengths", ["--model", "m", "--holdout-contents", "run", "--held-out", "--out", "r.json"]),
    ("experiments", "bmm_lafan1", ["--out", "r.json", "--prediction", "residual", "--learning-rate", "5e-4", "--min-snr-gamma", "0", "--steps", "9"]),
    ("benchmarks", "bmm_inference", ["--out", "results/bmm_inference.json"]),
    ("experiments", "delta_lafan1", ["--out", "results/delta_lafan1.json", "--modes", "main"]),
    ("experiments", "delta_anidance", ["--out", "results/delta_anidance.json"]),
    ("experiments", "train_ik", ["--corpus", "lafan1", "--out-dir", "~/.cache/bezmotion/runs/ik_lafan1"]),
    ("experiments", "ik_subsets", ["--out", "results/ik_subsets.json"]),
    ("experiments", "character_profiles", ["--out-dir", "bezmotion/assets/profiles"]),
    ("experiments", "cross_skeleton", ["--model", "lafan1=lafan1_cpu", "--out", "results/cross_skeleton.json"]),
    ("experiments", "clip_frame_detection", ["--every", "10", "--out", "results/clip_frame_detection.json"]),
    ("benchmarks", "delta_inference", []),
    ("benchmarks", "fk", []),
    ("benchmarks", "bvh_parse", []),
    ("benchmarks", "inbetween", ["--windows", "1", "2", "4", "--ik", "learned", "exact", "--out", "results/inbetween.json"]),
    ("benchmarks", "ik_exact", ["--repeats", "20", "--real", "40", "--out", "results/ik_exact_real.json"]),
    ("benchmarks", "ik_exact", ["--repeats", "20", "--parts", "--out", "results/ik_exact_parts.json"]),
]


@pytest.mark.parametrize(("folder", "name", "argv"), README_COMMANDS)
def test_readme_commands_parse(load_script, folder, name, argv):
    module = load_script(folder, name)
    args = parse_options(module.Options, argv)
    assert isinstance(args, module.Options)


def test_script_defaults_and_derived_settings(load_script, tmp_path, monkeypatch):
    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path))
    bmm = load_script("experiments", "bmm_lafan1")
    args = parse_options(bmm.Options, ["--out", "o", "--prediction", "residual", "--config", "tiny"])
    assert (args.steps, args.batch_size, args.learning_rate, args.min_snr_gamma, args.seeds) == (6000, 64, 1e-4, 5.0, (0,))
    assert args.table6_steps == (5, 10, 25, 50, 100) and args.run_dir == str(tmp_path / "runs" / "bmm_lafan1_tiny_residual")
    with pytest.raises(SystemExit):
        parse_options(bmm.Options, ["--out", "o", "--corpus", "bandai_namco", "--bandai-namco", "x"])

    delta = load_script("experiments", "delta_lafan1")
    args = parse_options(delta.Options, ["--out", "o"])
    assert (args.steps, args.batch_size, args.learning_rate, args.lengths, args.modes) == (3000, 64, 2e-4, (5, 15, 30, 45), "table3")
    assert args.run_dir == str(tmp_path / "runs" / "delta_lafan1_cpu")
    assert parse_options(delta.Options, ["--out", "o", "--run-dir", "/r/{name}-{config}"]).run_dir == "/r/delta_lafan1-cpu"

    anidance = load_script("experiments", "delta_anidance")
    args = parse_options(anidance.Options, ["--out", "o", "--steps", "0"])
    assert (args.steps, args.lengths, args.modes, args.min_gap, args.max_gap) == (0, (5, 15, 30), "table2", 4, 39)
    assert args.run_dir == str(tmp_path / "runs" / "delta_anidance_cpu")

    ik = load_script("experiments", "train_ik")
    args = ik.parse_args(["--corpus", "lafan1", "--no-effector-skip"])
    assert (args.steps, args.config, args.effector_skip, args.output_rotations) == (9000, "cpu", False, None)
    assert ik.parse_args(["--corpus", "lafan1", "--train-seconds", "330"]).train_seconds == 330.0
    with pytest.raises(SystemExit):
        ik.parse_args(["--corpus", "lafan1", "--train-seconds", "0"])


def test_the_ik_trains_without_held_out_contents(load_script, tmp_path, monkeypatch):
    """``train_ik.py --holdout-contents run``: no frame of a ``run`` clip is trained on."""
    import shutil

    from bezmotion.assets import DEMO_CLIP
    from bezmotion.ik.frames import corpus_frames

    monkeypatch.setenv("BEZMOTION_CACHE", str(tmp_path / "cache"))
    folder = tmp_path / "clips"
    folder.mkdir()
    for name in ("walk_1", "walk_2", "run_1", "walk_3", "run_2"):
        shutil.copy(DEMO_CLIP, folder / f"{name}.bvh")
    ik = load_script("experiments", "train_ik")
    corpus = ik.open_corpus(str(folder), data=None, characteristic="bandai_namco", progress=False)
    _, poses = corpus_frames(corpus, "train", frame_step=2)
    labels = [ik.clip_label(corpus.labels(int(c))) for c in corpus.split("train")]
    kept = ik.without_contents(corpus, poses, ("run",), 2)
    per_clip = poses.root_pos.shape[0] // len(labels)  # every clip is the same 40 frames, every 2nd kept
    assert "run" in labels and kept.root_pos.shape[0] == per_clip * labels.count("walk")
    np.testing.assert_array_equal(kept.quat_local[:per_clip], poses.quat_local[labels.index("walk") * per_clip :][:per_clip])
    with pytest.raises(ValueError, match=r"--holdout-contents jump: no training clip of .* has such a content \(it has \['run', 'walk'\]\)"):
        ik.without_contents(corpus, poses, ("jump",), 2)


@options
class Repeating:
    clip: Path | None = option(None, positional=True, help="a file")
    handle: tuple[str, ...] = option((), repeat=True, help="any number, flag repeated or not")
    label: str = option(positional=True)


def test_positional_and_repeated_options():
    args = parse_options(Repeating, ["a.bvh", "L", "--handle", "h1", "--handle", "h2", "h3"])
    assert args == Repeating(clip=Path("a.bvh"), handle=("h1", "h2", "h3"), label="L")
    assert parse_options(Repeating, ["L2"]) == Repeating(clip=None, handle=(), label="L2")
    with pytest.raises(SystemExit):
        parse_options(Repeating, [])  # the required positional is missing
    with pytest.raises(TypeError, match="repeat=True needs a tuple"):

        @options
        class Bad:
            n: int = option(1, repeat=True)

    with pytest.raises(TypeError, match="a positional option holds one value"):

        @options
        class Bad2:
            n: tuple[int, ...] = option((1,), positional=True)
