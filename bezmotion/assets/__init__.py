"""Small real data shipped with the package, so ``bezmotion demo`` and the tests run
without downloads. Attribution and licence: ``README.md`` in this folder."""

from pathlib import Path

ASSETS_DIR = Path(__file__).resolve().parent
DEMO_CLIP = ASSETS_DIR / "bandai_namco_walk_trimmed.bvh"
DEMO_CLIP_ATTRIBUTION = (
    "Bandai-Namco-Research-Motiondataset-2 (dataset-2_walk_normal_001, first 40 frames), "
    "(c) 2022 Bandai Namco Research Inc., CC BY-NC 4.0 (non-commercial)"
)
