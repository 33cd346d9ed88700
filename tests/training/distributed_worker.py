"""One process of the data-parallel training test (``test_distributed.py`` launches it).

    python distributed_worker.py RUN_DIR STEPS OUT.npz [COORDINATOR NUM_PROCESSES PROCESS_ID]

Trains the tiny BMM on the bundled clip's curves for STEPS steps (batch 8, resuming from
RUN_DIR's checkpoints when it has some) and, on process 0, saves the final state's leaves
to OUT.npz: arrays 0…n−1 are the state's leaves, n…2n−1 the same without the attention
key bias (see ``helpers.without_key_bias``). Without the last three arguments it runs as one ordinary process.
"""

from __future__ import annotations

import sys
from pathlib import Path

from bezmotion.training.distributed import DistributedOptions

if __name__ == "__main__":
    run_dir, steps, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    group = DistributedOptions(coordinator=sys.argv[4], num_processes=int(sys.argv[5]), process_id=int(sys.argv[6])) if len(sys.argv) > 4 else DistributedOptions()
    group.initialize()  # before any other JAX computation

    import jax
    import numpy as np

    from bezmotion.assets import DEMO_CLIP
    from bezmotion.bmm.denoiser import BMMConfig
    from bezmotion.bmm.features import FeatureStats
    from bezmotion.bmm.train import BMMTrainConfig, CurveArrays, init_bmm_train_states, make_bmm_train_step
    from bezmotion.data.bvh import read_bvh
    from bezmotion.data.corpus import MotionClips
    from bezmotion.data.curves import build_curve_dataset
    from bezmotion.training import CheckpointStore, compile_train_step, data_mesh, run_training
    from bezmotion.training.distributed import is_coordinator

    dataset = build_curve_dataset(MotionClips.from_bvh([read_bvh(DEMO_CLIP)]), "bandai_namco", window=31, offset=1, progress=False)
    model_config = BMMConfig.cpu(width=32, ff_width=64, num_heads=2, num_layers=1, dropout=0.0)
    train_config = BMMTrainConfig(batch_size=8, learning_rate=1e-3, ema_decay=0.9)
    graphdef, state = init_bmm_train_states(model_config, train_config, (0,))
    step = compile_train_step(
        make_bmm_train_step(graphdef, model_config, train_config, FeatureStats.from_dataset(dataset), mesh=data_mesh()),
        num_seeds=1,
    )
    store = CheckpointStore(run_dir)
    state, history = run_training(
        step, state, CurveArrays.from_dataset(dataset), num_steps=steps, store=store, config={"steps": steps},
        checkpoint_every=2, progress=False, log_every=1,
    )  # fmt: skip
    store.close()
    if is_coordinator():
        sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/, for helpers
        from helpers import leaves, without_key_bias

        np.savez(
            out,
            *leaves(state),
            *(leaves(without_key_bias(state))),
            losses=np.asarray([h["loss"] for h in history]),
            devices=jax.device_count(),
        )
