"""bezmotion: precise, character-agnostic motion in-betweening in JAX.

``import bezmotion as bm`` gives the verbs of the method, in the order data flows::

    clip = bm.read_bvh(bm.DEMO_CLIP)                      # mocap file → skeleton + local rotations
    character = bm.Character.from_bvh(clip, "bandai_namco")
    bmm, ik = bm.load_model(bm.BUNDLED_BMM), bm.load_ik_model(bm.BUNDLED_IK)
    result = bm.inbetween(bmm, bm.protores_ik_fn, ik, ik.character, start, end, handles, key=key)
    bm.write_bvh("out.bvh", bm.pose_to_bvh(ik.character, result.pose, template=clip))  # → file, rigged like the clip

Everything else lives in its subpackage (:mod:`bezmotion.geometry`, :mod:`bezmotion.bezier`,
:mod:`bezmotion.data`, :mod:`bezmotion.diffusion`, :mod:`bezmotion.training`,
:mod:`bezmotion.bmm`, :mod:`bezmotion.delta`, :mod:`bezmotion.ik`, :mod:`bezmotion.pipeline`,
:mod:`bezmotion.evaluation`). Modules inside the package import from those subpackages,
never from here, so this file can re-export anything without an import cycle.
"""

# Bundled data and models (paths; load them with the verbs below).
from bezmotion.assets import BUNDLED_BMM, BUNDLED_IK, DEMO_CLIP, PROFILES_DIR
from bezmotion.assets.registry import Pretrained, pretrained  # models by name: bm.pretrained("bandai_namco")

# Bézier curves.
from bezmotion.bezier import BezierLayout, evaluate, fit_curves

# The Bézier Motion Model: sampling curves through handles, saving and loading.
from bezmotion.bmm.sampling import (
    BezierMotionModel,
    Handles,
    SampledCurves,
    load_model,
    sample_chained_curves,
    sample_curves,
    save_model,
)

# Mocap files, corpora (published or a folder of your BVH files) and the six characteristic joints.
from bezmotion.data.bvh import BvhMotion, read_bvh, write_bvh
from bezmotion.data.corpus import Corpus
from bezmotion.data.sources import load_corpus
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS

# Skeletons and kinematics.
from bezmotion.geometry.skeleton import Skeleton, forward_kinematics, inverse_kinematics

# IK: the ik_fn(params, targets) -> pose protocol and its implementations.
from bezmotion.ik.protocol import Character, IKFn, IKTargets, Pose, pose_fk, pose_from_motion, targets_from_pose
from bezmotion.ik.protores import load_ik_model, protores_ik_fn, protores_refined_ik_fn, save_ik_model
from bezmotion.ik.rig import make_rig, rig_ik

# In-betweening end to end, character transfer, export (BVH, glTF, animated preview).
from bezmotion.pipeline.export import pose_to_bvh
from bezmotion.pipeline.gltf import read_glb, write_glb
from bezmotion.pipeline.inbetweening import ChainResult, InbetweenResult, inbetween, inbetween_chain
from bezmotion.pipeline.preview import write_preview
from bezmotion.pipeline.transfer import CharacterProfile, Transfer

__version__ = "0.1.0"

__all__ = [
    "BUNDLED_BMM",
    "BUNDLED_IK",
    "CHARACTERISTIC_JOINTS",
    "DEMO_CLIP",
    "PROFILES_DIR",
    "BezierLayout",
    "BezierMotionModel",
    "BvhMotion",
    "ChainResult",
    "Character",
    "CharacterProfile",
    "Corpus",
    "Handles",
    "IKFn",
    "IKTargets",
    "InbetweenResult",
    "Pose",
    "Pretrained",
    "SampledCurves",
    "Skeleton",
    "Transfer",
    "__version__",
    "evaluate",
    "fit_curves",
    "forward_kinematics",
    "inbetween",
    "inbetween_chain",
    "inverse_kinematics",
    "load_corpus",
    "load_ik_model",
    "load_model",
    "make_rig",
    "pose_fk",
    "pose_from_motion",
    "pose_to_bvh",
    "pretrained",
    "protores_ik_fn",
    "protores_refined_ik_fn",
    "read_bvh",
    "read_glb",
    "rig_ik",
    "sample_chained_curves",
    "sample_curves",
    "save_ik_model",
    "save_model",
    "targets_from_pose",
    "write_bvh",
    "write_glb",
    "write_preview",
]
