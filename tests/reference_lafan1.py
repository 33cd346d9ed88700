"""Independent plain-NumPy reference of the official LaFAN1 benchmark protocol.

Written only from the written specification (``../shared/REFERENCE.md`` section 1 and
``../shared/data/README.md``); it deliberately shares **no code** with ``bezmotion``
(its own BVH reader, quaternion helpers, FK, windowing and metrics), so that comparing
the two implementations catches bugs in either. Everything is float64 and written for
clarity rather than speed (explicit loops over joints, windows and time where that reads
more directly).

Entry point: :func:`reference_baselines` (``python -m tests.reference_lafan1 [zip]``
prints the table).

Data: LaFAN1 (Ubisoft La Forge), CC BY-NC-ND 4.0 — Harvey et al., "Robust Motion
In-betweening", SIGGRAPH 2020. Numbers on the 27-file subset are not comparable to the
numbers published on the full set.
"""

from __future__ import annotations

import re
import sys
import zipfile
from pathlib import Path

import numpy as np

N_PAST = 10  # frames 0..9 are the past context; frame 9 is the last past frame
TRANSITIONS = (5, 15, 30, 45)
TRAIN_SUBJECTS = (1, 2, 3, 4)
TEST_SUBJECTS = (5,)
TRAIN_WINDOW, TRAIN_OFFSET = 50, 20
TEST_WINDOW, TEST_OFFSET = 65, 40
CONTACT_THRESHOLD = 0.02  # squared per-frame displacement, cm^2
LEFT_FOOT, RIGHT_FOOT = (3, 4), (7, 8)

_AXES = {"X": np.array([1.0, 0.0, 0.0]), "Y": np.array([0.0, 1.0, 0.0]), "Z": np.array([0.0, 0.0, 1.0])}

# ---------------------------------------------------------------------------- quaternions
# Quaternions are stored (w, x, y, z) along the last axis.


def q_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b, written out component by component."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def q_inv(q: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion (its conjugate)."""
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def q_normalize(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def q_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate the 3-vector v by the unit quaternion q: the vector part of q ⊗ (0, v) ⊗ q*."""
    q, v = np.broadcast_arrays(q, np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], axis=-1))
    return q_mul(q_mul(q, v), q_inv(q))[..., 1:]


def q_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Quaternion of a rotation by ``angle`` (radians, any shape) about the unit ``axis``."""
    half = 0.5 * np.asarray(angle, dtype=np.float64)
    return np.concatenate([np.cos(half)[..., None], np.sin(half)[..., None] * axis], axis=-1)


def q_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Shortest-arc rotation taking the unit vector u onto the unit vector v.

    The rotation by angle θ about n = u×v/|u×v| has quaternion (cos θ/2, sin θ/2 · n);
    (1 + u·v, u×v) = 2 cos(θ/2) · (cos θ/2, sin θ/2 · n), so normalising it gives the answer.
    """
    u, v = np.broadcast_arrays(u, v)
    w = 1.0 + np.sum(u * v, axis=-1, keepdims=True)
    return q_normalize(np.concatenate([w, np.cross(u, v)], axis=-1))


def q_fix_continuity(q: np.ndarray) -> np.ndarray:
    """Temporal hemisphere fix along axis 0: frame t is negated when its dot product with
    the (already fixed) frame t-1 is negative. Works per joint (last axis = 4)."""
    out = np.array(q, dtype=np.float64, copy=True)
    for t in range(1, out.shape[0]):
        dot = np.sum(out[t] * out[t - 1], axis=-1)
        out[t] = np.where((dot < 0.0)[..., None], -out[t], out[t])
    return out


def q_slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Slerp as specified: normalise inputs; shortest path (negate one end when the dot is
    negative, decided before acos); normalised lerp when 1 - dot < 0.01; normalise output."""
    q0 = q_normalize(np.asarray(q0, dtype=np.float64))
    q1 = q_normalize(np.asarray(q1, dtype=np.float64))
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0.0, -q1, q1)  # shortest path, decided before acos
    dot = np.abs(dot)
    near = (1.0 - dot) < 0.01
    # spherical branch (evaluated on a safe dot where the lerp branch is taken)
    omega = np.arccos(np.where(near, 0.5, dot))
    s = np.sin(omega)
    spherical = (np.sin((1.0 - t) * omega) / s) * q0 + (np.sin(t * omega) / s) * q1
    linear = (1.0 - t) * q0 + t * q1
    return q_normalize(np.where(near, linear, spherical))


# -------------------------------------------------------------------------- BVH reading


def read_bvh_text(text: str) -> dict:
    """Minimal LaFAN1 BVH reader.

    Returns ``names`` (22), ``parents`` (int array, root -1), ``offsets`` (J, 3),
    ``rotations`` (T, J, 4) local quaternions after the temporal continuity fix,
    ``positions`` (T, J, 3) local positions (root animated, others = OFFSET).
    """
    lines = [ln.strip() for ln in text.replace("\r\n", "\n").replace("\r", "\n").split("\n")]
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[list[str]] = []
    stack: list[int | None] = []  # joint index per open '{' (None for End Site blocks)
    last: int | None = None  # last declared node (None = an End Site)
    motion_start = None
    for i, line in enumerate(lines):
        if not line:
            continue
        m = re.match(r"^(ROOT|JOINT)\s+(\S+)$", line)
        if m:
            parent = -1
            for s in reversed(stack):  # nearest enclosing joint
                if s is not None:
                    parent = s
                    break
            names.append(m.group(2))
            parents.append(parent)
            offsets.append([0.0, 0.0, 0.0])
            channels.append([])
            last = len(names) - 1
        elif re.match(r"^End\s+Site", line):
            last = None
        elif line == "{":
            stack.append(last)
        elif line == "}":
            stack.pop()
        elif line.startswith("OFFSET"):
            if last is not None:
                offsets[last] = [float(x) for x in line.split()[1:4]]
        elif line.startswith("CHANNELS"):
            parts = line.split()
            count = int(parts[1])
            channels[last] = parts[2 : 2 + count]
            assert len(channels[last]) == count
        elif line == "MOTION":
            motion_start = i
            break
    assert motion_start is not None, "no MOTION section"
    n_frames = int(re.match(r"^Frames:\s*(\d+)$", lines[motion_start + 1]).group(1))
    assert lines[motion_start + 2].startswith("Frame Time:")
    values = np.array(" ".join(lines[motion_start + 3 :]).split(), dtype=np.float64)
    n_channels = sum(len(c) for c in channels)
    assert values.size == n_frames * n_channels, (values.size, n_frames, n_channels)
    data = values.reshape(n_frames, n_channels)

    n_joints = len(names)
    offsets_arr = np.array(offsets, dtype=np.float64)
    rotations = np.zeros((n_frames, n_joints, 4))
    positions = np.broadcast_to(offsets_arr, (n_frames, n_joints, 3)).copy()
    col = 0
    for j in range(n_joints):
        q = np.zeros((n_frames, 4))
        q[:, 0] = 1.0
        pos_cols = {}
        for ch in channels[j]:
            if ch.endswith("position"):
                pos_cols[ch[0]] = col
            elif ch.endswith("rotation"):
                angle = data[:, col] * (np.pi / 180.0)
                # local rotation = product of the channel rotations in file order,
                # e.g. Zrotation Yrotation Xrotation -> qz(e0) ⊗ qy(e1) ⊗ qx(e2)
                q = q_mul(q, q_axis_angle(_AXES[ch[0]], angle))
            else:
                raise ValueError(ch)
            col += 1
        rotations[:, j] = q
        if pos_cols:
            assert j == 0, "only the root position is animated in LaFAN1"
            positions[:, j] = data[:, [pos_cols["X"], pos_cols["Y"], pos_cols["Z"]]]
    rotations = q_fix_continuity(rotations)
    return {
        "names": names,
        "parents": np.array(parents, dtype=int),
        "offsets": offsets_arr,
        "rotations": rotations,
        "positions": positions,
    }


# ---------------------------------------------------------------------------------- FK


def fk(rot: np.ndarray, pos: np.ndarray, parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward kinematics; rot (..., J, 4), pos (..., J, 3) local → global (rot, pos)."""
    g_rot = np.empty(np.broadcast_shapes(rot.shape[:-1], pos.shape[:-1]) + (4,))
    g_pos = np.empty(g_rot.shape[:-1] + (3,))
    for j, p in enumerate(parents):
        if p < 0:
            g_rot[..., j, :] = rot[..., j, :]
            g_pos[..., j, :] = pos[..., j, :]
        else:
            g_rot[..., j, :] = q_mul(g_rot[..., p, :], rot[..., j, :])
            g_pos[..., j, :] = q_rotate(g_rot[..., p, :], pos[..., j, :]) + g_pos[..., p, :]
    return g_rot, g_pos


def inverse_fk(g_rot: np.ndarray, g_pos: np.ndarray, parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Global (rot, pos) → local (rot, pos)."""
    rot = np.empty_like(g_rot)
    pos = np.empty_like(g_pos)
    for j, p in enumerate(parents):
        if p < 0:
            rot[..., j, :] = g_rot[..., j, :]
            pos[..., j, :] = g_pos[..., j, :]
        else:
            inv_parent = q_inv(g_rot[..., p, :])
            rot[..., j, :] = q_mul(inv_parent, g_rot[..., j, :])
            pos[..., j, :] = q_rotate(inv_parent, g_pos[..., j, :] - g_pos[..., p, :])
    return rot, pos


# ----------------------------------------------------------------------------- windows


def foot_contacts(g_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contacts for windows (..., T, J, 3): squared per-frame displacement < 0.02, last
    frame duplicated. Returns (..., T, 2) booleans for left (3, 4) and right (7, 8)."""
    out = []
    for joints in (LEFT_FOOT, RIGHT_FOOT):
        feet = g_pos[..., list(joints), :]  # (..., T, 2, 3)
        disp = feet[..., 1:, :, :] - feet[..., :-1, :, :]
        c = np.sum(disp**2, axis=-1) < CONTACT_THRESHOLD  # (..., T-1, 2)
        out.append(np.concatenate([c, c[..., -1:, :]], axis=-2))
    return out[0], out[1]


def process_window(rot: np.ndarray, pos: np.ndarray, parents: np.ndarray) -> dict:
    """Windows (..., T, J, ·) (one or a stack of independent windows, time axis -3):
    contacts, XZ-centering, rotation around Y at frame 9, each window on its own."""
    rot = np.array(rot, dtype=np.float64, copy=True)
    pos = np.array(pos, dtype=np.float64, copy=True)
    # (1) contacts from FK of the raw window
    _, g_pos_raw = fk(rot, pos, parents)
    c_l, c_r = foot_contacts(g_pos_raw)
    # (2) XZ centering of the root by the window mean (mean over the window's frames)
    for axis in (0, 2):
        root_coord = pos[..., :, 0, axis]  # (..., T)
        pos[..., :, 0, axis] = root_coord - np.mean(root_coord, axis=-1, keepdims=True)
    # (3) rotate around Y at frame 9
    g_rot, g_pos = fk(rot, pos, parents)
    key = g_rot[..., N_PAST - 1, 0, :]  # (..., 4) root global rotation at frame 9
    forward = q_rotate(key, np.broadcast_to(np.array([0.0, 1.0, 0.0]), key.shape[:-1] + (3,)))
    forward[..., 1] = 0.0
    forward = forward / np.linalg.norm(forward, axis=-1, keepdims=True)
    yrot = q_between(np.array([1.0, 0.0, 0.0]), forward)  # (..., 4)
    yinv = q_inv(yrot)[..., None, None, :]  # broadcast over (T, J)
    g_rot = q_mul(np.broadcast_to(yinv, g_rot.shape), g_rot)
    g_pos = q_rotate(np.broadcast_to(yinv, g_rot.shape), g_pos)
    rot, pos = inverse_fk(g_rot, g_pos, parents)
    return {"rotations": rot, "positions": pos, "contacts_l": c_l, "contacts_r": c_r}


def window_starts(n_frames: int, window: int, offset: int) -> list[int]:
    starts = []
    start = 0
    while start + window < n_frames:  # strict
        starts.append(start)
        start += offset
    return starts


def _subject(name: str) -> int:
    m = re.match(r"^(.+)_subject(\d+)\.bvh$", name)
    assert m, name
    return int(m.group(2))


def load_zip(zip_path) -> list[tuple[str, dict]]:
    """All top-level ``*.bvh`` members, parsed, in sorted file-name order."""
    out = []
    with zipfile.ZipFile(zip_path) as zf:
        names = sorted(n for n in zf.namelist() if n.endswith(".bvh") and "/" not in n)
        for name in names:
            out.append((name, read_bvh_text(zf.read(name).decode("utf-8"))))
    return out


def extract_set(files: list[tuple[str, dict]], subjects, window: int, offset: int) -> dict:
    rots, poss, cls, crs = [], [], [], []
    parents = None
    for name, bvh in files:
        if _subject(name) not in subjects:
            continue
        if parents is None:
            parents = bvh["parents"]
        assert np.array_equal(parents, bvh["parents"])
        n_frames = bvh["rotations"].shape[0]
        starts = window_starts(n_frames, window, offset)
        if not starts:
            continue
        # all windows of this file, stacked (each processed independently)
        w = process_window(
            np.stack([bvh["rotations"][s : s + window] for s in starts]),
            np.stack([bvh["positions"][s : s + window] for s in starts]),
            parents,
        )
        rots.append(w["rotations"])
        poss.append(w["positions"])
        cls.append(w["contacts_l"])
        crs.append(w["contacts_r"])
    return {
        "rotations": np.concatenate(rots),
        "positions": np.concatenate(poss),
        "contacts_l": np.concatenate(cls),
        "contacts_r": np.concatenate(crs),
        "parents": parents,
    }


def train_statistics(files) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x_mean, x_std (66,) over (windows, frames) of global positions; offsets (21, 3)."""
    train = extract_set(files, TRAIN_SUBJECTS, TRAIN_WINDOW, TRAIN_OFFSET)
    _, g_pos = fk(train["rotations"], train["positions"], train["parents"])
    flat = g_pos.reshape(-1, g_pos.shape[-2] * 3)  # (windows*frames, 66)
    x_mean = flat.mean(axis=0)
    x_std = flat.std(axis=0)  # population std (ddof 0)
    offsets = train["positions"][0, 0, 1:, :].copy()  # first training window, non-root joints
    return x_mean, x_std, offsets


# ----------------------------------------------------------------------------- metrics


def l2q(gq_pred: np.ndarray, gq_gt: np.ndarray) -> float:
    b, n = gq_gt.shape[:2]
    d = gq_pred.reshape(b, n, -1) - gq_gt.reshape(b, n, -1)
    return float(np.mean(np.sqrt(np.sum(d**2, axis=-1))))


def l2p(gp_pred: np.ndarray, gp_gt: np.ndarray, x_std: np.ndarray) -> float:
    b, n = gp_gt.shape[:2]
    d = (gp_pred.reshape(b, n, -1) - gp_gt.reshape(b, n, -1)) / x_std
    return float(np.mean(np.sqrt(np.sum(d**2, axis=-1))))


def npss(gq_pred: np.ndarray, gq_gt: np.ndarray) -> float:
    b, n = gq_gt.shape[:2]
    pred = gq_pred.reshape(b, n, -1)
    gt = gq_gt.reshape(b, n, -1)
    p_pow = np.real(np.fft.fft(pred, axis=1)) ** 2
    g_pow = np.real(np.fft.fft(gt, axis=1)) ** 2
    p_tot = p_pow.sum(axis=1)  # (B, 88)
    g_tot = g_pow.sum(axis=1)
    p_cdf = np.cumsum(p_pow / p_tot[:, None, :], axis=1)
    g_cdf = np.cumsum(g_pow / g_tot[:, None, :], axis=1)
    emd = np.sum(np.abs(p_cdf - g_cdf), axis=1)  # L1 over time, (B, 88)
    return float(np.sum(emd * g_tot) / np.sum(g_tot))


def _delta_fix(gq: np.ndarray, gq_last_past: np.ndarray) -> np.ndarray:
    """Δ-interpolator variant: prepend the last past frame's global quaternion, fix
    hemisphere continuity over time, drop the prepended frame. gq (B, n, J, 4)."""
    out = np.empty_like(gq)
    for b in range(gq.shape[0]):
        seq = np.concatenate([gq_last_past[b][None], gq[b]], axis=0)
        out[b] = q_fix_continuity(seq)[1:]
    return out


# --------------------------------------------------------------------------- benchmark


def _benchmark(test: dict, x_std: np.ndarray, offsets: np.ndarray, variant: str) -> dict:
    parents = test["parents"]
    Q = test["rotations"]  # (B, 65, J, 4)
    root = test["positions"][:, :, 0, :]  # (B, 65, 3)
    n_win = Q.shape[0]

    def global_of(local_rot, root_pos):
        local_pos = np.concatenate(
            [root_pos[..., None, :], np.broadcast_to(offsets, root_pos.shape[:-1] + offsets.shape)], axis=-2
        )
        return fk(local_rot, local_pos, parents)

    last_past_gq, _ = global_of(Q[:, N_PAST - 1], root[:, N_PAST - 1])  # (B, J, 4)
    res = {"zerov": {"l2q": {}, "l2p": {}, "npss": {}}, "interp": {"l2q": {}, "l2p": {}, "npss": {}}}
    for n in TRANSITIONS:
        key = N_PAST + n
        gt_q = Q[:, N_PAST : N_PAST + n]
        gt_r = root[:, N_PAST : N_PAST + n]
        zv_q = np.repeat(Q[:, N_PAST - 1 : N_PAST], n, axis=1)
        zv_r = np.repeat(root[:, N_PAST - 1 : N_PAST], n, axis=1)
        ip_q = np.empty_like(gt_q)
        ip_r = np.empty_like(gt_r)
        for k in range(1, n + 1):
            t = k / (n + 1)
            ip_q[:, k - 1] = q_slerp(Q[:, N_PAST - 1], Q[:, key], t)
            ip_r[:, k - 1] = (1.0 - t) * root[:, N_PAST - 1] + t * root[:, key]
        gt_gq, gt_gp = global_of(gt_q, gt_r)
        for name, lq, lr in (("zerov", zv_q, zv_r), ("interp", ip_q, ip_r)):
            gq, gp = global_of(lq, lr)
            q_pred, q_gt = gq, gt_gq
            if variant == "delta":
                q_pred = _delta_fix(gq, last_past_gq)
                q_gt = _delta_fix(gt_gq, last_past_gq)
            elif variant != "official":
                raise ValueError(variant)
            res[name]["l2q"][str(n)] = l2q(q_pred, q_gt)
            res[name]["l2p"][str(n)] = l2p(gp, gt_gp, x_std)
            res[name]["npss"][str(n)] = npss(q_pred, q_gt)
    return {"n_windows": int(n_win), **res}


_CACHE: dict = {}


def _prepared(zip_path) -> tuple:
    key = str(Path(zip_path).resolve())
    if key not in _CACHE:
        files = load_zip(zip_path)
        x_mean, x_std, offsets = train_statistics(files)
        test = extract_set(files, TEST_SUBJECTS, TEST_WINDOW, TEST_OFFSET)
        _CACHE[key] = (x_mean, x_std, offsets, test)
    return _CACHE[key]


def reference_baselines(zip_path, variant: str = "official") -> dict:
    """Zero-velocity and interpolation baselines under the official LaFAN1 protocol.

    ``variant="official"`` is the La Forge evaluator; ``variant="delta"`` applies the
    Δ-interpolator's hemisphere handling to L2Q/NPSS (L2P is unchanged).
    """
    _, x_std, offsets, test = _prepared(zip_path)
    return _benchmark(test, x_std, offsets, variant)


if __name__ == "__main__":
    import json
    import time

    path = sys.argv[1] if len(sys.argv) > 1 else str(
        Path(__file__).resolve().parents[2] / "shared" / "data" / "lafan1" / "lafan1-subset.zip"
    )
    t0 = time.perf_counter()
    out = {v: reference_baselines(path, variant=v) for v in ("official", "delta")}
    elapsed = time.perf_counter() - t0
    print(json.dumps(out, indent=1))
    print(f"# {elapsed:.1f} s", file=sys.stderr)
