"""Small real data shipped with the package, so ``bezmotion demo`` and the tests run
without downloads. Attribution and licence: ``README.md`` in this folder."""

from pathlib import Path

ASSETS_DIR = Path(__file__).resolve().parent
DEMO_CLIP = ASSETS_DIR / "bandai_namco_walk_trimmed.bvh"
DEMO_CLIP_ATTRIBUTION = (
    "Bandai-Namco-Research-Motiondataset-2 (dataset-2_walk_normal_001, first 40 frames), "
    "(c) 2022 Bandai Namco Research Inc., CC BY-NC 4.0 (non-commercial)"
)
PROFILES_DIR = ASSETS_DIR / "profiles"
"""Character profiles (:class:`bezmotion.pipeline.inbetweening.CharacterProfile`) of the bundled
corpora's skeletons, measured by ``experiments/character_profiles.py``."""
MODELS_DIR = ASSETS_DIR / "models"
BUNDLED_BMM = MODELS_DIR / "bmm_bandai_namco"
"""The small pretrained BMM ``bezmotion demo`` uses (see ``README.md`` here for how it was trained)."""
BUNDLED_IK = MODELS_DIR / "ik_bandai_namco"
"""The small pretrained learned IK for the Bandai-Namco skeleton."""
