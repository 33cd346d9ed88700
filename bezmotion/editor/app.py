"""The browser editor of ``bezmotion edit``: an :class:`~bezmotion.editor.EditSession` drawn
and driven through viser (``pip install -e '.[editor]'``).

    app = serve(session)            # http://127.0.0.1:8080, until app.stop()

The 3-D view shows the body at the timeline's frame (its bones as line segments), the clip's
own motion as a grey ghost, the six Bézier curves with their control points, and a gizmo
per handle: dragging one calls :meth:`EditSession.drag` (the curves and body follow), letting
go :meth:`EditSession.release` (a full resample). The panel adds and deletes handles,
resamples and flips back to an earlier seed, undoes and redoes, sets the keys (a chain),
toggles foot lock, key velocities and the IK, exports and reopens a handles file, and lists
the handles missed and the warnings; clicking a joint's ball adds a handle on it at the
timeline's frame. Every session call holds one lock (viser runs callbacks in
threads); gizmo moves queue in order and a move superseded by a later one is dropped.

Every request needs the session's random token (:mod:`bezmotion.editor.access`), which
:attr:`EditorApp.url` carries; the server listens on 127.0.0.1 unless told otherwise.
The scene is in metres (the session's cm × 0.01), Y up.
"""

from __future__ import annotations

import contextlib
import io
import queue
import sys
import threading
from typing import Any, Callable, NamedTuple
from urllib.parse import quote

import numpy as np

from bezmotion._src.messages import one_line
from bezmotion.data.characteristic import CHARACTERISTIC_JOINTS
from bezmotion.editor.access import TokenGate, gated_viser
from bezmotion.editor.session import EditSession, EditView

SCALE = 0.01
"""Metres per cm: the scene's unit is the metre, the session's the cm."""

FPS = 30.0
"""Frames a second while playing."""

LOOPBACK = ("127.0.0.1", "localhost", "::1")
"""Hosts that only this machine reaches."""

CURVE_COLOURS = ((230, 160, 40), (200, 60, 200), (40, 120, 230), (230, 60, 60), (40, 180, 200), (60, 180, 60))
"""An RGB colour per characteristic joint's curve (hips, head, hands, feet)."""


class GizmoMove(NamedTuple):
    """A gizmo event: handle ``handle_id`` at ``position`` (cm); ``phase`` start, update or end."""

    handle_id: int
    position: np.ndarray
    phase: str


# ------------------------------------------------------------------------------- geometry


def bone_segments(joints: np.ndarray, parents: Any, hips: int = 0) -> np.ndarray:
    """``(bones, 2, 3)`` m: a segment from each joint's parent to it, of ``joints`` ``(joints, 3)`` cm.

    Joints above ``hips`` (a world root that stays at the origin or on the floor) draw no bone:
    a line from the floor to the body is no part of it."""
    above = set()
    j = hips
    while j >= 0:
        j = parents[j]
        above.add(j)
    pairs = [(p, j) for j, p in enumerate(parents) if p >= 0 and p not in above]
    return np.asarray([[joints[p], joints[j]] for p, j in pairs], np.float32).reshape(-1, 2, 3) * SCALE


def bezier_points(ctrl_pos: np.ndarray, ctrl_tangent: np.ndarray, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """One curve's ``(points (controls, 3), control points (2·(controls − 1), 3))`` m, as
    viser's cubic Bézier spline takes them, from ``ctrl_pos``/``ctrl_tangent`` ``(controls, 3)``
    cm of a curve over ``frames`` frames (a control point every stride frames, the last
    segment possibly shorter: :mod:`bezmotion.bezier`)."""
    controls = ctrl_pos.shape[0]
    stride = -(-(frames - 1) // (controls - 1))
    at = np.minimum(np.arange(controls) * stride, frames - 1)
    scale = (np.diff(at) / stride)[:, None]
    first = ctrl_pos[:-1] + scale * ctrl_tangent[:-1]
    second = ctrl_pos[1:] - scale * ctrl_tangent[1:]
    inner = np.stack([first, second], axis=1).reshape(-1, 3)
    return np.asarray(ctrl_pos, np.float32) * SCALE, np.asarray(inner, np.float32) * SCALE


def coalesced(moves: list[GizmoMove]) -> list[GizmoMove]:
    """``moves`` in order without those a later move of the same gesture supersedes: an
    update followed by another update or the end of that handle, and every start (a drag
    begins with its first update)."""
    kept = []
    for i, move in enumerate(moves):
        later = moves[i + 1] if i + 1 < len(moves) else None
        superseded = later is not None and later.handle_id == move.handle_id and later.phase != "start"
        if move.phase == "start" or (move.phase == "update" and superseded):
            continue
        kept.append(move)
    return kept


def status_text(view: EditView, message: str) -> str:
    """The panel's text (markdown): ``message``, then each handle's error in cm, the misses and warnings."""
    lines = [message] if message else []
    lines += [f"handle {h}: {error:.3f} cm" for h, error in sorted(view.handle_errors.items())]
    lines += [f"miss: {line}" for line in view.misses] + [f"warning: {line}" for line in view.warnings]
    return "  \n".join(lines) if lines else "every handle met"


# ------------------------------------------------------------------------------- the app


class EditorApp:
    """A viser server showing and editing ``session`` (see the module docstring); made by :func:`serve`.

    Attributes:
      server: the ``viser.ViserServer``.
      gate: the token check every request passes.
      session: the session edited (call it only under :attr:`lock`).
      lock: held around every session call.
      message: the last action's outcome or error, as the panel shows it.
      ready: set once the session's first view is drawn.
    """

    def __init__(self, session: EditSession, server: Any, gate: TokenGate, *, background: bool = False) -> None:
        self.session, self.server, self.gate = session, server, gate
        self.lock = threading.RLock()
        self.message = ""
        self._moves: queue.SimpleQueue[GizmoMove | None] = queue.SimpleQueue()
        self._stopped = threading.Event()
        self._flushes: queue.SimpleQueue[threading.Event] = queue.SimpleQueue()
        self._gizmos: dict[int, Any] = {}
        self._balls: dict[str, Any] = {}
        server.scene.set_up_direction("+y")
        # viser's share button opens a public tunnel to the session: not from the editor.
        server.gui.configure_theme(show_share_button=False)
        server.request_share_url = self._refuse_share
        self._build_gui()
        self._worker = threading.Thread(target=self._drain_moves, name="bezmotion-gizmos", daemon=True)
        self._worker.start()
        self._player = threading.Thread(target=self._play_loop, name="bezmotion-play", daemon=True)
        self._player.start()
        self.ready = threading.Event()
        if background:
            self._aim_camera(self.session.ghost[:, session.character.hips])
            self._draw_ghost(int(self.frame.value))
            self.status.content = "sampling the in-between…"
            threading.Thread(target=self._first_view_then_warm_up, name="bezmotion-first-view", daemon=True).start()
        else:
            self._first_view()

    def _first_view(self) -> None:
        with self.lock:
            view = self.session.view
            self._aim_camera(view.positions[:, 0])
            self._redraw(view, gizmos=True)
        self.ready.set()

    def _first_view_then_warm_up(self) -> None:
        try:
            self._first_view()
            with self.lock:
                self.session.warm_up()
        except Exception as error:  # noqa: BLE001 - shown on the page: the thread has no caller
            self.message = one_line(f"{type(error).__name__}: {error}")
            self.status.content = self.message

    @property
    def url(self) -> str:
        """The address to open in a browser, with the token."""
        return f"{self.base_url}/?token={quote(self.gate.token, safe='')}"

    @property
    def base_url(self) -> str:
        """The server's address without the token (which answers 403)."""
        host = self.server.get_host()
        host = "127.0.0.1" if host in ("0.0.0.0", "") else f"[{host}]" if ":" in host else host
        return f"http://{host}:{self.server.get_port()}"

    def _refuse_share(self, *_: Any, **__: Any) -> None:
        self.message = "sharing is off: the editor stays on its own address"
        return None

    def stop(self) -> None:
        """Stop playing, the gizmo worker and the server."""
        self._stopped.set()
        self._moves.put(None)
        self._worker.join(timeout=5)
        self._player.join(timeout=5)
        self.server.stop()

    # --------------------------------------------------------------------- GUI

    def _build_gui(self) -> None:
        gui, session = self.server.gui, self.session
        last = max(session.frames - 1, 1)
        with gui.add_folder("Timeline"):
            self.frame = gui.add_slider("Frame", min=0, max=last, step=1, initial_value=min(12, last))
            self.playing = gui.add_checkbox("Play", initial_value=False)
        with gui.add_folder("Handles"):
            self.joint = gui.add_dropdown("Joint", CHARACTERISTIC_JOINTS, initial_value="right_hand")
            self.add_button = gui.add_button("Add handle", hint="a handle on the joint's curve at the timeline's frame")
            self.handle = gui.add_dropdown("Handle", ("none",), initial_value="none")
            self.delete_button = gui.add_button("Delete handle")
        with gui.add_folder("Keys"):
            self.keys = gui.add_text("Key frames", initial_value=" ".join(map(str, session.state.keys)), hint="clip frames, 30 apart: more than two make a chain")
            self.keys_button = gui.add_button("Set keys")
        with gui.add_folder("Sample"):
            self.resample_button = gui.add_button("Resample")
            self.seed = gui.add_dropdown("Seed", tuple(map(str, session.seeds)) or (str(session.state.seed),), initial_value=str(session.state.seed))
            self.undo_button = gui.add_button("Undo")
            self.redo_button = gui.add_button("Redo")
            self.foot_lock = gui.add_checkbox("Foot lock", initial_value=session.state.options.foot_lock)
            self.key_velocities = gui.add_checkbox("Key velocities", initial_value=session.state.key_velocities)
            self.ik = gui.add_dropdown("IK", session.ik_choices, initial_value=session.state.ik)
        with gui.add_folder("Files"):
            self.export_name = gui.add_text("Name", initial_value="edit", hint="a plain name: files go in the output folder")
            self.export_button = gui.add_button("Export")
            self.open_button = gui.add_button("Open handles", hint="NAME.handles.json from the output folder")
        self.status = gui.add_markdown("")
        self.frame.on_update(lambda _: self._redraw_frame())
        self.add_button.on_click(lambda _: self._edit(self._add_handle))
        self.delete_button.on_click(lambda _: self._edit(self._delete_handle))
        self.resample_button.on_click(lambda _: self._edit(lambda: self.session.resample()))
        self.undo_button.on_click(lambda _: self._edit(lambda: self.session.undo()))
        self.redo_button.on_click(lambda _: self._edit(lambda: self.session.redo()))
        self.foot_lock.on_update(lambda _: self._edit(lambda: self.session.set_foot_lock(bool(self.foot_lock.value))))
        self.key_velocities.on_update(lambda _: self._edit(lambda: self.session.set_key_velocities(bool(self.key_velocities.value))))
        self.export_button.on_click(lambda _: self._edit(self._export))
        self.open_button.on_click(lambda _: self._edit(self._open_handles))
        self.keys_button.on_click(lambda _: self._edit(self._set_keys))
        self.seed.on_update(lambda _: self._edit(self._use_seed))
        self.ik.on_update(lambda _: self._edit(self._set_ik))

    def _set_keys(self) -> str:
        text = str(self.keys.value)
        try:
            frames = [int(word) for word in text.replace(",", " ").split()]
        except ValueError:
            raise ValueError(f"key frames are whole numbers, e.g. 0 30, got {one_line(repr(text), 60)}") from None
        self.session.set_keys(frames)
        return f"keys at clip frames {' '.join(map(str, frames))}"

    def _use_seed(self) -> str | None:
        seed = int(self.seed.value)
        if seed == self.session.state.seed:
            return None  # the dropdown following a resample or an undo
        self.session.use_seed(seed)
        return f"seed {seed}"

    def _set_ik(self) -> str | None:
        if self.ik.value == self.session.state.ik:
            return None
        self.session.set_ik(str(self.ik.value))
        return f"IK {self.ik.value}"

    def _open_handles(self) -> str:
        name = str(self.export_name.value)
        file = name if name.endswith((".json", ".toml")) else f"{name}.handles.json"  # an export's name, or a file's
        self.session.open_handles(file)
        return f"opened {file}"

    def _add_handle_on(self, joint: str) -> str:
        """A handle on ``joint`` at the timeline's frame (a click on the joint's ball)."""
        if self.joint.value != joint:
            self.joint.value = joint
        return self._add_handle()

    def _add_handle(self) -> str:
        handle_id = self.session.add_handle(self.joint.value, int(self.frame.value))
        return f"added handle {handle_id}: {self.joint.value} at frame {int(self.frame.value)}"

    def _delete_handle(self) -> str:
        if self.handle.value == "none":
            raise ValueError("no handle to delete: add one first")
        self.session.delete_handle(int(self.handle.value))
        return f"deleted handle {self.handle.value}"

    def _export(self) -> str:
        files = self.session.export(str(self.export_name.value))
        return "exported " + ", ".join(path.name for path in files.values())

    def _edit(self, action: Callable[[], Any]) -> None:
        """Run ``action`` (a session edit; its string, if any, is the message; ``None``: it had
        nothing to do) under the lock, then redraw; a ``ValueError`` becomes the message and
        changes nothing."""
        with self.lock:
            try:
                outcome = action()
                if outcome is None:  # nothing to do (a control following the state): no message, no redraw
                    return
                self.message = outcome if isinstance(outcome, str) else ""
            except ValueError as error:
                self.message = f"error: {one_line(str(error))}"
            self._sync_toggles()
            self._redraw(self.session.view, gizmos=True)

    def _sync_toggles(self) -> None:
        """The checkboxes as the state has them (after an undo, or a refused toggle)."""
        state = self.session.state
        if self.foot_lock.value != state.options.foot_lock:
            self.foot_lock.value = state.options.foot_lock
        if self.key_velocities.value != state.key_velocities:
            self.key_velocities.value = state.key_velocities
        seeds = tuple(map(str, self.session.seeds)) or (str(state.seed),)
        if tuple(self.seed.options) != seeds:
            self.seed.options = seeds
        if self.seed.value != str(state.seed):
            self.seed.value = str(state.seed)
        if self.ik.value != state.ik:
            self.ik.value = state.ik
        keys = " ".join(map(str, state.keys))
        if self.keys.value.split() != keys.split():
            self.keys.value = keys

    # --------------------------------------------------------------------- gizmos

    def move(self, handle_id: int, position_cm: Any, phase: str) -> None:
        """Queue a gizmo event (what dragging a handle's gizmo does): ``phase`` start, update
        or end, ``position_cm`` ``(3,)`` cm. The worker drags, and releases at the end."""
        self._moves.put(GizmoMove(int(handle_id), np.asarray(position_cm, np.float64), str(phase)))

    def settle(self, timeout: float = 30.0) -> None:
        """Wait until every queued gizmo event has been handled (``timeout`` s at most)."""
        done = threading.Event()
        self._flushes.put(done)
        self._moves.put(GizmoMove(-1, np.zeros(3), "flush"))
        done.wait(timeout)

    def _drain_moves(self) -> None:
        while not self._stopped.is_set():
            moves = [self._moves.get()]
            while not self._moves.empty():
                moves.append(self._moves.get())
            if any(move is None for move in moves):
                return
            for move in coalesced([m for m in moves if m.phase != "flush"]):
                self._apply(move)
            for _ in range(sum(m.phase == "flush" for m in moves)):
                self._flushes.get().set()

    def _apply(self, move: GizmoMove) -> None:
        with self.lock:
            try:
                view = self.session.drag(move.handle_id, move.position)
                if move.phase == "end":
                    view = self.session.release()
                self.message = ""
            except ValueError as error:
                self.message = f"error: {one_line(str(error))}"
                view = self.session.cancel_drag()
            self._redraw(view, gizmos=move.phase == "end")

    def _gizmo_callback(self, handle_id: int) -> Callable[[Any], Any]:
        async def on_update(event: Any) -> None:  # async: viser keeps the phases in order
            self.move(handle_id, np.asarray(event.target.position) / SCALE, event.phase)

        return on_update

    # --------------------------------------------------------------------- drawing

    def _aim_camera(self, hips_cm: np.ndarray) -> None:
        """Look at the hips' path ``(frames, 3)`` cm from the side, far enough to see all of it (3 m at least)."""
        hips = hips_cm * SCALE
        centre = hips.mean(axis=0)
        distance = max(3.0, 2.0 * float(np.ptp(hips, axis=0).max()))
        self.server.initial_camera.look_at = centre
        self.server.initial_camera.position = centre + distance * np.array([0.6, 0.35, 0.7])

    def _play_loop(self) -> None:
        while not self._stopped.wait(1.0 / FPS):
            if self.playing.value:
                self.frame.value = (int(self.frame.value) + 1) % (int(self.frame.max) + 1)

    def _redraw_frame(self) -> None:
        with self.lock:
            self._draw_bodies(self.session.view)

    def _redraw(self, view: EditView, *, gizmos: bool) -> None:
        """Draw ``view``: bodies, curves, text; the gizmos too where ``gizmos`` (not mid-drag)."""
        last = self.session.frames - 1
        if int(self.frame.max) != last:
            self.frame.max = last
            self.frame.value = min(int(self.frame.value), last)
        self._draw_bodies(view)
        self._draw_curves(view)
        if gizmos:
            self._draw_gizmos()
        self.status.content = status_text(view, self.message)

    def _draw_bodies(self, view: EditView) -> None:
        frame = min(int(self.frame.value), view.joints.shape[0] - 1)
        parents, hips = self.session.character.skeleton.parents, self.session.character.hips
        scene = self.server.scene
        scene.add_line_segments("/body", bone_segments(view.joints[frame], parents, hips), (30, 30, 30), thickness=0.02)
        self._draw_ghost(frame)
        self._draw_joint_balls(view.positions[frame])

    def _draw_joint_balls(self, positions_cm: np.ndarray) -> None:
        """A ball on each of the six joints' curves at the timeline's frame; clicking one adds
        a handle there (made once, then moved)."""
        for j, name in enumerate(CHARACTERISTIC_JOINTS):
            position = positions_cm[j] * SCALE
            ball = self._balls.get(name)
            if ball is None:
                ball = self.server.scene.add_icosphere(f"/joints/{name}", radius=0.025, color=CURVE_COLOURS[j], position=position)
                ball.on_click(lambda _, name=name: self._edit(lambda: self._add_handle_on(name)))
                self._balls[name] = ball
            elif not np.allclose(ball.position, position):
                ball.position = position

    def _draw_ghost(self, frame: int) -> None:
        ghost, character = self.session.ghost, self.session.character
        segments = bone_segments(ghost[min(frame, ghost.shape[0] - 1)], character.skeleton.parents, character.hips)
        self.server.scene.add_line_segments("/ghost", segments, (170, 170, 170), thickness=0.01)

    def _draw_curves(self, view: EditView) -> None:
        ctrl_pos, ctrl_tangent = np.asarray(view.curves.ctrl_pos), np.asarray(view.curves.ctrl_tangent)
        frames = view.positions.shape[0]
        for j, name in enumerate(CHARACTERISTIC_JOINTS):
            points, inner = bezier_points(ctrl_pos[:, j], ctrl_tangent[:, j], frames)
            colour = CURVE_COLOURS[j]
            self.server.scene.add_spline_cubic_bezier(f"/curves/{name}", points, inner, color=colour, thickness=0.008)
            self.server.scene.add_point_cloud(f"/controls/{name}", points, colour, point_size=0.03)

    def _draw_gizmos(self) -> None:
        handles = {h.id: h for h in self.session.state.handles}
        for handle_id in [h for h in self._gizmos if h not in handles]:
            self._gizmos.pop(handle_id).remove()
        for handle_id, handle in handles.items():
            position = np.asarray(handle.position) * SCALE
            gizmo = self._gizmos.get(handle_id)
            if gizmo is None:
                gizmo = self.server.scene.add_transform_controls(f"/handles/{handle_id}", scale=0.2, disable_rotations=True, position=position)
                gizmo.on_update(self._gizmo_callback(handle_id))
                self._gizmos[handle_id] = gizmo
            elif not np.allclose(gizmo.position, position):
                gizmo.position = position
        names = tuple(str(h) for h in handles) or ("none",)
        self.handle.options = names
        if self.handle.value not in names:
            self.handle.value = names[-1]


def serve(
    session: EditSession, host: str = "127.0.0.1", port: int = 8080, *, token: str | None = None, background: bool = False, verbose: bool = False
) -> EditorApp:
    """Serve the browser editor of ``session`` on ``host:port`` (``port=0``: any free one) and
    return it; it runs in the background until :meth:`EditorApp.stop`.

    It returns once the session's first view is drawn; with ``background``, at once, the page
    showing the clip while a thread samples the first view (:attr:`EditorApp.ready` is set
    then) and compiles the drag (:meth:`EditSession.warm_up`); edits wait for both.

    Every request needs ``token`` (default: a fresh random one), which :attr:`EditorApp.url`
    carries. A host other than the loopback lets whoever reaches it and knows the token edit
    the session and export into its folder; the token travels unencrypted (plain HTTP).

    Raises:
      ValueError: a port outside 0–65535, or an empty token.
      ImportError: viser is not installed (``pip install -e '.[editor]'``).
      RuntimeError: this viser version starts its server in a way the token check cannot wrap.
    """
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ValueError(f"a port is an integer in 0…65535, got {one_line(repr(port), 40)}")
    if token is not None and not (isinstance(token, str) and token):
        raise ValueError(f"a token is a non-empty string, got {one_line(repr(token), 40)}")
    try:
        import viser
    except ImportError:
        raise ImportError("the browser editor needs viser: pip install -e '.[editor]'") from None
    gate = TokenGate.new() if token is None else TokenGate(token)
    server = None
    try:
        # viser prints its own banner with the address sans token (which answers 403): hush it.
        with gated_viser(gate), contextlib.redirect_stdout(sys.stdout if verbose else io.StringIO()):
            server = viser.ViserServer(host=host, port=port, verbose=verbose)
        return EditorApp(session, server, gate, background=background)
    except BaseException:
        if server is not None:
            server.stop()
        raise


__all__ = ["CURVE_COLOURS", "FPS", "LOOPBACK", "SCALE", "EditorApp", "GizmoMove", "bezier_points", "bone_segments", "coalesced", "serve"]
