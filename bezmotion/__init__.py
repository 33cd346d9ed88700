"""bezmotion: precise, character-agnostic motion in-betweening in JAX.

``import bezmotion as bm``; one model object, one entry point::

    clip = bm.read_bvh("my_walk.bvh")                              # any humanoid skeleton
    model = bm.Inbetweener.from_bvh(clip)                          # or bm.pretrained("bandai_namco")
    keys = model.poses(clip, [0, 30])                              # two keys: one window
    handles = model.handles({"right_hand": (12, (0, 25, 0))}, relative_to=keys)  # frame, cm
    result = model.inbetween(keys, handles, key=jax.random.key(0)) # = bm.inbetween(model, …)
    # keys any distance apart: model.inbetween_at(model.poses(clip, [0, 20, 65]), [0, 20, 65], …)
    bm.write_bvh("out.bvh", model.to_bvh(result, template=clip))

Everything else lives in its subpackage (:mod:`bezmotion.geometry`, :mod:`bezmotion.bezier`,
:mod:`bezmotion.data`, :mod:`bezmotion.diffusion`, :mod:`bezmotion.training`,
:mod:`bezmotion.bmm`, :mod:`bezmotion.delta`, :mod:`bezmotion.ik`, :mod:`bezmotion.pipeline`,
:mod:`bezmotion.evaluation`). Modules inside the package import from those subpackages,
never from here, so this file can re-export anything without an import cycle.
"""

# The model object and the one entry point.
from bezmotion.pipeline.model import Inbetweener, pretrained
from bezmotion.pipeline.inbetweening import InbetweenOptions, InbetweenResult, inbetween
from bezmotion.pipeline.key_times import TimedInbetween, inbetween_at

# What they take and give.
from bezmotion.bmm.sampling import BezierMotionModel, Handles, SampledCurves, load_model, sample_curves, save_model
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.ik.protocol import Character, IKFn, IKTargets, Pose
from bezmotion.pipeline.transfer import Transfer

# Files: BVH in and out, glTF with the curves, an animated preview; the bundled clip.
from bezmotion.assets import DEMO_CLIP
from bezmotion.data.bvh import BvhMotion, read_bvh, write_bvh
from bezmotion.pipeline.gltf import read_glb, write_glb
from bezmotion.pipeline.preview import write_preview

__version__ = "0.1.0"

__all__ = [
    "CHARACTERISTIC_JOINTS",
    "DEMO_CLIP",
    "BezierMotionModel",
    "BvhMotion",
    "Character",
    "Handles",
    "IKFn",
    "IKTargets",
    "InbetweenOptions",
    "InbetweenResult",
    "Inbetweener",
    "Pose",
    "SampledCurves",
    "TimedInbetween",
    "Transfer",
    "__version__",
    "inbetween",
    "inbetween_at",
    "load_model",
    "pretrained",
    "read_bvh",
    "read_glb",
    "sample_curves",
    "save_model",
    "write_bvh",
    "write_glb",
    "write_preview",
]
