"""Animated preview (GIF) of an in-between: the 3-D skeleton, the six Bézier curves with
their control points and tangent handles, the user's handles, beside the mocap.

:func:`write_preview` draws one GIF frame per motion frame (Matplotlib's 3-D axes,
rendered off screen, written by Pillow). The camera follows the character: every frame
is centred on the hips' horizontal position at a fixed scale. Without a reference motion
the start and end poses (the input keys) are drawn as grey ghosts instead of a second
panel. Our Y-up world is shown Z-up, ``(x, −z, y)`` (a rotation, not a mirror).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bezmotion.bezier import DEFAULT_STRIDE, BezierLayout, checked_controls
from bezmotion.data.bvh import BvhMotion
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.ik.protocol import Character
from bezmotion._src.io import atomic_path


def _fk(motion: BvhMotion) -> np.ndarray:
    """``(frames, joints, 3)`` global positions (cm) by forward kinematics in NumPy (float64)."""
    q = np.asarray(motion.quat_local, np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    t = np.asarray(motion.pos_local, np.float64)
    parents = motion.skeleton.parents
    rot = np.empty(q.shape[:-1] + (3, 3))
    w, x, y, z = np.moveaxis(q, -1, 0)
    rot[..., 0, :] = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1)
    rot[..., 1, :] = np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1)
    rot[..., 2, :] = np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)
    glob_rot, glob_pos = np.empty_like(rot), np.empty_like(t)
    for j, p in enumerate(parents):
        if p < 0:
            glob_rot[:, j], glob_pos[:, j] = rot[:, j], t[:, j]
        else:
            glob_rot[:, j] = glob_rot[:, p] @ rot[:, j]
            glob_pos[:, j] = glob_pos[:, p] + np.einsum("fij,fj->fi", glob_rot[:, p], t[:, j])
    return glob_pos


def _dense_curves(layout: BezierLayout, ctrl_pos: np.ndarray, ctrl_tangent: np.ndarray, per_frame: int = 4) -> np.ndarray:
    """``(samples, 6, 3)`` points along the curves (the 4-point form of :func:`bezmotion.bezier.to_segments`)."""
    scale = (layout.segment_lengths / layout.stride)[:, None, None]
    p0, p3 = ctrl_pos[:-1], ctrl_pos[1:]
    p1, p2 = p0 + scale * ctrl_tangent[:-1], p3 - scale * ctrl_tangent[1:]
    out = []
    for k, length in enumerate(layout.segment_lengths):
        t = np.linspace(0.0, 1.0, per_frame * int(length) + 1)[:-1, None, None]
        u = 1.0 - t
        out.append(u**3 * p0[k] + 3 * u * u * t * p1[k] + 3 * u * t * t * p2[k] + t**3 * p3[k])
    out.append(ctrl_pos[-1:])
    return np.concatenate(out)


def _view(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Our Y-up points ``(..., 3)`` as Matplotlib's Z-up ``(x, −z, y)`` coordinate arrays."""
    return p[..., 0], -p[..., 2], p[..., 1]


def _view_points(p: np.ndarray) -> np.ndarray:
    """:func:`_view` stacked: ``(..., 3)`` points in Matplotlib's Z-up frame (line segments, collections)."""
    return np.stack(_view(p), axis=-1)


def write_preview(
    path: str | os.PathLike,
    character: Character,
    motion: BvhMotion,
    ctrl_pos: np.ndarray | None = None,
    ctrl_tangent: np.ndarray | None = None,
    *,
    stride: int = DEFAULT_STRIDE,
    reference: BvhMotion | None = None,
    handles: Sequence[Mapping[str, Any]] | None = None,
    title: str | None = None,
    dpi: float | int = 72,
    size: tuple[float, float] | None = None,
    layout: BezierLayout | None = None,
) -> int:
    """Write an animated GIF of ``motion`` with its curves, one GIF frame per motion frame (atomically).

    Args:
      path: the ``.gif`` to write.
      character: the character the motion is of (its hips, characteristic joints, and the
        static joints above the hips, which are not drawn).
      motion: the in-between, e.g. ``pose_to_bvh(character, result.pose, fps=...)``
        (:func:`bezmotion.pipeline.export.pose_to_bvh`): same joint names as ``character``;
        its frame time sets the GIF's.
      ctrl_pos, ctrl_tangent: ``(controls, 6, 3)`` the curves (cm, world frame,
        :data:`CHARACTERISTIC_JOINTS` order; ``InbetweenResult.curves``), drawn with their
        control points and tangent handles; both or neither.
      stride: frames between control points (the BMM's ``config.stride``).
      reference: the mocap (same number of frames, any skeleton) drawn in a second panel
        beside the in-between, with the same camera; without it the start and end poses
        are drawn as ghosts.
      handles: ``[{"joint": "right_hand", "frame": 12, "position": [x, y, z]}]`` (cm), drawn as stars.
      title: a line above the panels.
      dpi, size: resolution and figure size in inches (default 4.8 × 4.2 per panel).
      layout: where the curves' control points sit (default ``BezierLayout(frames, stride)``;
        keys at unequal distances: :attr:`~bezmotion.pipeline.key_times.TimedInbetween.layout`).
    Returns:
      the number of GIF frames (``motion``'s frame count).

    Raises:
      ValueError: joints not of ``character``, curves of the wrong shape, a reference of
        another length, bad handles.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection
    from PIL import Image

    names = motion.skeleton.names
    if tuple(names) != tuple(character.skeleton.names):
        raise ValueError(f"motion joints {list(names)} are not {character.name}'s {list(character.skeleton.names)}")
    frames = motion.quat_local.shape[0]
    layout = BezierLayout(frames, stride) if layout is None else layout
    if layout.num_frames != frames:
        raise ValueError(f"the curves' layout has {layout.num_frames} frames, the motion {frames}")
    ctrl_pos, ctrl_tangent = checked_controls(ctrl_pos, ctrl_tangent, layout, len(CHARACTERISTIC_JOINTS))
    if reference is not None and reference.quat_local.shape[0] != frames:
        raise ValueError(f"reference has {reference.quat_local.shape[0]} frames, the motion {frames}")
    marks = []
    for i, h in enumerate(handles or ()):
        position = np.asarray(h.get("position", ()), np.float64) if isinstance(h, Mapping) else np.zeros(0)
        if not isinstance(h, Mapping) or h.get("joint") not in CHARACTERISTIC_JOINTS or position.shape != (3,):
            raise ValueError(f"handle {i} must be {{'joint': one of {list(CHARACTERISTIC_JOINTS)}, 'frame', 'position': [x, y, z]}}, got {h!r}")
        marks.append((h["joint"], int(h["frame"]), position))

    pos = _fk(motion)
    ref = _fk(reference) if reference is not None else None
    hips, idx = character.hips, list(character.characteristic)
    hidden = set(character.ancestors_of_hips())
    bones = np.asarray([(p, j) for j, p in enumerate(character.skeleton.parents) if p >= 0 and p not in hidden], dtype=int).reshape(-1, 2)
    ref_bones = np.zeros((0, 2), int)
    if reference is not None:
        ref_hidden = hidden if reference.skeleton.names == names else set()
        ref_bones = np.asarray([(p, j) for j, p in enumerate(reference.skeleton.parents) if p >= 0 and p not in ref_hidden], dtype=int).reshape(-1, 2)
    colours = plt.cm.tab10(np.arange(len(CHARACTERISTIC_JOINTS)))
    dense = _dense_curves(layout, ctrl_pos, ctrl_tangent) if ctrl_pos is not None else None

    # Camera: a fixed-size box centred on the hips; tall enough for the whole motion.
    drawn = [pos[:, [j for j in range(len(names)) if j not in hidden]]] + ([ref] if ref is not None else [])
    everything = np.concatenate([d.reshape(-1, 3) for d in drawn])
    height = max(everything[:, 1].max(), 1.0)
    floor = min(everything[:, 1].min(), 0.0)
    half = 0.45 * (height - floor)
    panels = 2 if ref is not None else 1
    fig = plt.figure(figsize=size or (4.8 * panels, 4.2), dpi=dpi)
    axes = [fig.add_subplot(1, panels, i + 1, projection="3d") for i in range(panels)]
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=0.9, wspace=0.0)
    label = fig.suptitle("", fontsize=9)

    # Every group of segments (tangent handles, bones) is one collection: Matplotlib's 3-D axes
    # draw each artist with its own projection, and one line per segment made the preview take
    # seconds (about 240 artists a frame).
    def segments(ax, segs: np.ndarray, **style) -> Line3DCollection:
        lines = Line3DCollection(_view_points(segs), **style)
        ax.add_collection3d(lines, autolim=False)
        return lines

    def static(ax, with_curves: bool) -> None:
        ax.set_box_aspect((1.0, 1.0, (height - floor) / (2 * half)), zoom=1.2)
        ax.view_init(elev=12, azim=-60)
        # Moving tick labels say nothing in a following camera; the floor grid shows the motion.
        ax.set_xticklabels([])
        ax.set_yticklabels([])
        ax.set_zticklabels([])
        if with_curves and dense is not None:
            for c in range(len(CHARACTERISTIC_JOINTS)):
                ax.plot(*_view(dense[:, c]), color=colours[c], lw=1.0, label=CHARACTERISTIC_JOINTS[c])
                ax.plot(*_view(ctrl_pos[:, c]), "o", color=colours[c], ms=2.5)
            # Tangent handles as animation tools draw them: P − a_{k−1}·T to P + a_k·T.
            lengths = layout.segment_lengths / layout.stride
            before = np.concatenate([lengths[:1], lengths])[:, None, None]
            after = np.concatenate([lengths, lengths[-1:]])[:, None, None]
            ends = np.stack([ctrl_pos - before * ctrl_tangent, ctrl_pos + after * ctrl_tangent], axis=-2)  # (controls, 6, 2, 3)
            handle_colours = np.tile(colours, (layout.num_controls, 1))  # one per (control, joint), joint fastest
            segments(ax, ends.reshape(-1, 2, 3), colors=handle_colours, linewidths=0.6, alpha=0.7)
            ax.scatter(*_view(ends.reshape(-1, 3)), marker="|", s=9, c=np.repeat(handle_colours, 2, axis=0), alpha=0.7, depthshade=False)
        for joint, _, p in marks:
            ax.plot(*_view(p[None]), "*", color="purple", ms=9)

    static(axes[0], True)
    axes[0].set_title("in-between" + (" (grey: input keys)" if ref is None else ""), fontsize=8)
    if ref is None:
        segments(axes[0], np.concatenate([pos[key][bones] for key in (0, frames - 1)]), colors="0.6", linewidths=1.0, alpha=0.6)
    else:
        static(axes[1], True)
        axes[1].set_title("mocap", fontsize=8)
        ref_idx = [list(reference.skeleton.names).index(names[j]) for j in idx] if reference.skeleton.names == names else []
        for c, j in enumerate(ref_idx):
            axes[1].plot(*_view(ref[:, j]), "--", color=colours[c], lw=0.8, alpha=0.8)
    if dense is not None:
        axes[0].legend(fontsize=5, loc="upper left", ncol=2)

    skeleton = segments(axes[0], pos[0][bones], colors="k", linewidths=1.6)
    moving = [axes[0].plot([], [], [], "o", color=colours[c], ms=4)[0] for c in range(len(CHARACTERISTIC_JOINTS))]
    ref_skeleton = segments(axes[1], ref[0][ref_bones], colors="0.25", linewidths=1.6) if ref is not None else None

    images = []
    for f in range(frames):
        skeleton.set_segments(_view_points(pos[f][bones]))
        for c, line in enumerate(moving):
            line.set_data_3d(*_view(pos[f, idx[c]][None]))
        if ref_skeleton is not None:
            ref_skeleton.set_segments(_view_points(ref[f][ref_bones]))
        centre = pos[f, hips]
        for ax in axes:
            ax.set_xlim(centre[0] - half, centre[0] + half)
            ax.set_ylim(-centre[2] - half, -centre[2] + half)
            ax.set_zlim(floor, height)
        at_handle = [f"{j}" for j, hf, _ in marks if hf == f]
        label.set_text(f"{title + ' · ' if title else ''}frame {f}/{frames - 1}" + (f"  handle: {', '.join(at_handle)}" if at_handle else ""))
        fig.canvas.draw()
        images.append(Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[..., :3]).convert("P", palette=Image.Palette.ADAPTIVE, colors=64))  # lines on white: 64 colours suffice
    plt.close(fig)
    duration = max(10, round(1000.0 * motion.frame_time))  # ms; GIF stores hundredths of a second
    with atomic_path(path, suffix=".gif") as tmp:
        # The frame counter differs on every frame, so Pillow merges none: one GIF frame per motion frame.
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=duration, loop=0)
    return frames
