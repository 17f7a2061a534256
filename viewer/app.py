"""``particlesplat-viewer``: the desktop app (glfw window, moderngl, imgui-bundle native backends).

The frame loop only pumps events and draws frames. Idle, it sleeps in ``glfw.wait_events()`` and
draws nothing; it draws on input (a few frames, :mod:`viewer.redraw`), and once more when a motion
stops (the full-scale frame). Panels and mouse tools change the session (edits, do/undo) and the
view state; :class:`~viewer.scene_view.SceneView` re-renders only when those or the camera changed.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import sys
import time
from pathlib import Path

import glfw  # noqa: E402  (after imgui_bundle on purpose)
import moderngl  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from imgui_bundle import imgui  # import before glfw so both use the same GLFW library

from particlesplat.core.camera import Camera  # noqa: E402
from particlesplat.core.outputs import OutputError, guard_outputs  # noqa: E402
from particlesplat.core.userdirs import autosave_dir, output_dir  # noqa: E402
from particlesplat.core.viewpoints import (
    View,
    check_fov,
    default_view,  # noqa: E402
    parse_look,
    scene_background,
)

from .chords import ChordQueue, install_ctrl_grace  # noqa: E402
from .commands import carry_out, save_edits  # noqa: E402
from .controls import Viewport, ViewportControls  # noqa: E402
from .display import NoDisplay, check_display  # noqa: E402
from .gl.caps import UnsupportedGL  # noqa: E402
from .gl.renderer import SplatRenderer  # noqa: E402
from .loading import load_session, particle_swatches, source_inputs  # noqa: E402
from .opening import PROGRESS_EVERY, Opening, load_opened, open_arguments, start_opening  # noqa: E402
from .orbit import OrbitCamera  # noqa: E402
from .particle_overlay import ParticleOverlay  # noqa: E402
from .redraw import CURSOR_BLINK, RedrawSchedule, install_event_callbacks  # noqa: E402
from .scene_view import SceneView  # noqa: E402
from .screenshot import png_text, save_png, save_screenshot  # noqa: E402
from .session import EditableScene, Scene, session_particles  # noqa: E402
from .settings import load_settings, save_settings  # noqa: E402
from .signals import SignalStop  # noqa: E402
from .state import ViewState  # noqa: E402
from .tools.crop_box import draw_crop_box  # noqa: E402
from .tools.crop_handles import CropHandles  # noqa: E402
from .tools.object_tools import ObjectGizmo  # noqa: E402
from .tools.ruler import draw_ruler  # noqa: E402
from .ui.objects import copy_step  # noqa: E402
from .ui.panel import UiFields, UiRequests, clear_of_panel, draw_overlay, draw_panel, draw_status_line  # noqa: E402

STILL_AFTER = 0.2  # seconds without interaction before rendering at full scale
ORBIT_STEP = 1.0  # degrees per frame with --orbit


def window_address(window) -> int:
    """The address of a glfw window (what imgui's glfw backend takes)."""
    addr = ctypes.cast(window, ctypes.c_void_p).value
    if addr is None:
        raise RuntimeError("no GL window")
    return addr


def session_background(session: Scene) -> tuple[float, float, float]:
    """The colour behind the session's scene (:func:`scene_background`): its particles' own where they read it
    from their views."""
    return scene_background(session.model, session_particles(session))


def initial_view(session: Scene, look: str | None, fov: float | None) -> View:
    """Default view of the session (framed as its scene.json records, else by its cameras), with ``--look`` /
    ``--fov`` applied."""
    from particlesplat.data.scene_meta import read_framing

    framing = read_framing(session.source) if session.cameras and session.source else None
    base = default_view(session.cameras or None, None if session.cameras else session.gaussians(), framing)
    lk = parse_look(look) if look else base.look
    return View(base.target, lk, check_fov(fov) if fov is not None else base.fov)


class App:
    """One window: its GL context, renderer, session, state and UI."""

    def __init__(
        self, window, session: Scene, view: View, args: argparse.Namespace, ctx: moderngl.Context | None = None
    ) -> None:
        self.window = window
        # (moderngl detects a window's context once: pass ``ctx`` to open another App on the same window)
        self.ctx = ctx if ctx is not None else moderngl.create_context()
        self.args = args
        self.scene_view = SceneView(
            SplatRenderer(self.ctx, primitive=args.primitive, compositing=args.compositing)  # the default 16-bit target
        )
        self.session = session
        self.orbit = OrbitCamera.from_view(view)
        self.state = ViewState(panel=not args.no_ui, background=session_background(session))
        self.req = UiRequests()
        self.settings = load_settings()
        out = str(args.output_dir or output_dir())
        self.fields = UiFields(output_dir=out, panel_width=self.settings.panel_width)
        self.fields.objects.copy_offset = copy_step(view.look.distance)  # at the scene's scale
        self.fields.edits_path = str(session.default_edits_path(out))
        self.chords = ChordQueue()  # Ctrl chords with the modifiers of their key events
        self._frame_chords: list[tuple[str, bool]] = []
        self._shown_status = ""  # the status line last mirrored on the terminal
        self._mode_note: str | None = None  # what note_mode last said
        self.controls = ViewportControls()
        self.gizmo = ObjectGizmo()  # world-space handles and outline of the selected object
        self.crop_handles = CropHandles()  # the crop box's face handles
        self.particle_overlay = ParticleOverlay()  # keypoints / boxes segmentation modes
        self.frame_times: list[float] = []
        self.opening: Opening | None = None  # a scene being opened on a thread (viewer.opening)
        self.background_open = True  # open scenes on a thread (run with frames: at once)
        self.swatches = particle_swatches(session)
        self._swatched = session.num_owners()  # the particle count the swatches are of
        self.redraw = RedrawSchedule()
        self.stop: SignalStop | None = None  # set while signals end the loop (:mod:`viewer.signals`)
        self._xsync = None  # the display's sync call (False: none), found on the first frame
        self._watch_events()

    def _watch_events(self) -> None:
        """Route every window event to :attr:`redraw`, under imgui's callbacks (which chain to ours)."""
        from imgui_bundle.imgui import backends

        addr = window_address(self.window)
        backends.glfw_restore_callbacks(addr)
        install_event_callbacks(self.window, self.redraw.notify, routed=True)
        backends.glfw_install_callbacks(addr)
        # the pointer, buttons, keys and characters reach imgui through the Ctrl grace (a Ctrl a moment late counts),
        # and the chords with the modifiers their key events carried
        self.grace = install_ctrl_grace(self.window, addr, self.redraw.notify, self.chords.on_key)

    # ------------------------------------------------------------------ frame
    def framebuffer_size(self) -> tuple[int, int]:
        w, h = glfw.get_framebuffer_size(self.window)
        return max(int(w), 1), max(int(h), 1)

    def render_scale(self) -> float:
        moving = time.perf_counter() - self.controls.last_move < STILL_AFTER
        return self.state.moving_scale if moving else 1.0

    def view_camera(self, scale: float = 1.0, clear_panel: bool = True) -> Camera:
        """The orbit camera at the framebuffer size x ``scale``; with the panel shown (and ``clear_panel``) it
        frames the scene in the part of the window the panel leaves free."""
        w, h = self.framebuffer_size()
        cam = self.orbit.camera(max(1, round(w * scale)), max(1, round(h * scale)))
        if clear_panel and self.state.panel:
            cam = clear_of_panel(cam, self.pixel_ratio()[0] * scale, self.fields.panel_width)
        return cam

    def frame(self, show_ui: bool = True) -> bool:
        """One frame: UI, input, render if changed, present. Returns whether it changed anything
        (re-rendered the scene or carried out a panel request), and schedules the next timed
        redraw (:attr:`redraw`)."""
        from imgui_bundle.imgui import backends

        self.grace.flush()  # presses held for a Ctrl that did not come within their time go on now
        self.poll_opening()
        backends.opengl3_new_frame()
        backends.glfw_new_frame()
        imgui.new_frame()
        if show_ui:
            message = self.gizmo.draw(
                self.session, self.state.selected, self.view_camera(1.0), self.pixel_ratio(), self.state.gizmo_scale
            )
            self.particle_overlay.draw(self.session, self.state.seg_mode, self.view_camera(1.0), self.pixel_ratio())
            draw_ruler(self.state, self.view_camera(1.0), self.pixel_ratio())
            draw_crop_box(self.session, self.view_camera(1.0), self.pixel_ratio())
            message = (
                self.crop_handles.draw(self.session, self.view_camera(1.0), self.pixel_ratio(), self.gizmo.capturing)
                or message
            )
            if message:
                self.fields.status = message
            self._frame_chords = self.chords.take()
            self.controls.handle(self.viewport())
            self._frame_chords = []
            if self.state.panel:
                if self.session.num_owners() != self._swatched:  # copies and inserted objects get theirs
                    self.swatches, self._swatched = particle_swatches(self.session), self.session.num_owners()
                drawn = self.scene_view.renderer.visible_count
                draw_panel(
                    self.session,
                    self.state,
                    self.req,
                    self.fields,
                    self.swatches,
                    (drawn, self.scene_view.renderer.num),
                    self.orbit.current_camera,
                )
                self.remember_panel_width()
            self.note_mode()
            if self.state.overlay:
                draw_overlay(self.overlay_lines())
            draw_status_line(self.fields, self.fields.panel_width if self.state.panel else 0.0)
        else:
            self.chords.take()  # no UI: no shortcuts
        imgui.render()
        requested = self.process_requests()
        self.mirror_status()
        scale = self.render_scale()
        rendered = self.scene_view.draw(self.session, self.state, self.view_camera(scale)) is not None
        fw, fh = self.framebuffer_size()
        self.ctx.screen.use()
        self.ctx.viewport = (0, 0, fw, fh)
        self.scene_view.present(self.state, (0, 0, fw, fh))
        backends.opengl3_render_draw_data(imgui.get_draw_data())
        glfw.swap_buffers(self.window)
        self.display_sync()
        changed = rendered or requested
        # input imgui has not taken yet (it takes one change of a key or button a frame): draw until it has,
        # so fast taps (Ctrl+Z, Ctrl+Y) are all done now, not at the next event
        queued = len(imgui.get_current_context().input_events_queue) > 0
        self.redraw.drawn(changed or queued, self.next_wake(scale))
        return changed

    def note_mode(self) -> None:
        """Say on the status line what the mode shows when it changes to something to say (a mask with nothing
        selected: :meth:`ViewState.mode_note`), once, not every frame."""
        note = self.state.mode_note()
        if note is not None and note != self._mode_note:
            self.fields.status = note
        self._mode_note = note

    def mirror_status(self) -> None:
        """Print a new status line on the terminal too (saved, exported, errors), where a user who looks away from
        the window, or whose window is small, still sees it."""
        status = self.fields.status
        if status and status != self._shown_status:
            print(f"particlesplat-viewer: {' '.join(status.split())}", flush=True)
        self._shown_status = status

    def remember_panel_width(self) -> None:
        """Keep the panel's width in the settings file once the user has dragged its edge (mouse released)."""
        width = self.fields.panel_width
        if abs(width - self.settings.panel_width) < 0.5 or imgui.is_mouse_down(imgui.MouseButton_.left):
            return
        self.settings.panel_width = width
        try:
            save_settings(self.settings)
        except OSError as e:  # a read-only home: the width holds for this run
            self.fields.status = f"error: the panel width is not remembered: {e}"

    def display_sync(self) -> None:
        """Wait until the display server has taken the frame just swapped (X11: ``XSync``), so at most one frame
        is ever in flight: on a busy machine a server that falls behind would otherwise keep showing frames the
        input has overtaken (a drag going on after the mouse was released)."""
        if self._xsync is None:
            self._xsync = _x11_sync_function()
        if self._xsync:
            self._xsync()

    def next_wake(self, scale: float) -> float | None:
        """When to draw without input: the full-scale frame once a motion stops, the cursor of an
        active text field; None when nothing changes by itself."""
        if self.opening is not None:  # the progress line of a scene being opened
            return time.perf_counter() + PROGRESS_EVERY
        if scale < 1.0:
            return self.controls.last_move + STILL_AFTER
        if imgui.get_io().want_text_input:
            return time.perf_counter() + CURSOR_BLINK
        return None

    def overlay_lines(self) -> list[str]:
        t = self.frame_times[-30:]
        ms = float(np.median(t)) * 1e3 if t else 0.0
        r = self.scene_view.renderer
        last = self.scene_view.last_times
        lines = [
            f"{ms:6.1f} ms/frame (median of the last 30), render scale {self.render_scale():.2f}, "
            f"{r.compositing} compositing",
            f"{r.visible_count:,} of {r.num:,} Gaussians, {last.primitive or '-'}, sort {last.sort_ms:.1f} ms",
        ]
        editor = self.session.editor
        if editor is not None:
            active = sum(editor.is_active(i) for i in range(editor.num_particles))
            lines.append(
                f"{active} of {editor.num_particles} particles active"
                + (f", selected {self.state.selected}" if self.state.selected is not None else "")
            )
        lines.append(f"mode: {self.state.seg_mode}")
        return lines

    # ------------------------------------------------------------------ input
    def viewport(self) -> Viewport:
        """What the controls work on this frame: the orbit camera, state, session, requests, the viewing camera,
        the picker and the status line."""

        def status(message: str) -> None:
            self.fields.status = message

        return Viewport(
            orbit=self.orbit,
            state=self.state,
            session=self.session,
            requests=self.req,
            camera=lambda: self.view_camera(1.0),
            pick=lambda x, y: self.scene_view.pick(self.session, self.view_camera(1.0), x, y),
            status=status,
            pixel_ratio=self.pixel_ratio(),
            height=self.framebuffer_size()[1],
            copy_offset=self.fields.objects.copy_offset,
            gizmo_capturing=self.gizmo.capturing or self.crop_handles.capturing,
            chords=self._frame_chords,
        )

    def pixel_ratio(self) -> tuple[float, float]:
        """Framebuffer pixels per window coordinate (HiDPI)."""
        ww, wh = glfw.get_window_size(self.window)
        fw, fh = self.framebuffer_size()
        return fw / max(ww, 1), fh / max(wh, 1)

    # ------------------------------------------------------------------ requests
    def process_requests(self) -> bool:
        """Carry out the panel's requests (:mod:`viewer.commands`); returns whether there were any."""
        req, self.req = self.req, UiRequests()
        if req == UiRequests():
            return False
        carry_out(self, req)
        return True

    def save_edits(self) -> Path | None:
        """Save the edits to the 'edits YAML' path (:func:`viewer.commands.save_edits`); None for a .ply."""
        return save_edits(self.session, self.fields) if isinstance(self.session, EditableScene) else None

    def keep_unsaved(self) -> Path | None:
        """Autosave the session's unsaved edits (before it is replaced or the window closes); returns the file."""
        return self.session.autosave(autosave_dir())

    def open(self, path: str) -> None:
        """Open a scene folder or a Gaussian file (.ply, .compressed.ply, .splat, .spz, .sog; replaces the
        session), now. Unsaved edits of the old scene are autosaved first; autosaved edits of the new one are offered
        (the edits path is set: Load restores them)."""
        # a bad path (or scene.json) changes nothing
        new, view = load_opened(open_arguments(self.args, path), lambda _: None, lambda s: initial_view(s, None, None))
        self.adopt(path, new, view)

    def open_in_background(self, path: str) -> None:
        """Open ``path`` on a thread while the window goes on (:mod:`viewer.opening`): the status line shows its
        progress, :meth:`poll_opening` puts it in place once ready. Run with ``frames`` (benchmarks, tests), it is
        opened now (:meth:`open`)."""
        if not self.background_open:
            self.open(path)
            return
        if self.opening is not None:
            self.fields.status = f"{self.opening.line()}: wait for it before opening {path}"
            return
        self.opening = start_opening(self.args, path, lambda s: initial_view(s, None, None))
        self.fields.status = self.opening.line()

    def poll_opening(self) -> None:
        """Once a frame: the progress of a scene being opened on the status line, or, once it is ready, the scene in
        place (:meth:`adopt`); what went wrong instead as an error, the scene shown staying as it is."""
        opening = self.opening
        if opening is None:
            return
        if not opening.done:
            self.fields.status = opening.line()
            return
        self.opening = None
        try:
            if opening.error is not None:
                raise opening.error
            assert opening.result is not None
            self.adopt(opening.path, *opening.result)
            self.fields.status += f" ({time.perf_counter() - opening.started:.1f} s)"
        except Exception as e:  # noqa: BLE001 - a bad path or file must not close the app: show it
            self.fields.status = f"error: {e}"
        self.redraw.notify()

    def adopt(self, path: str, new: Scene, view: View) -> None:
        """Show ``new`` (opened from ``path``) from ``view`` in place of the scene shown, its unsaved edits autosaved
        first (OutputError, nothing changed, when they cannot be)."""
        p = Path(path)
        try:
            kept = self.keep_unsaved()
        except OutputError as e:  # the scene stays open with its edits: nothing is lost
            raise OutputError(f"{e}; {p} not opened: save the edits elsewhere (Save edits) first") from None
        self.session = new
        self.swatches, self._swatched = particle_swatches(self.session), self.session.num_owners()
        self.state = ViewState(
            panel=self.state.panel, overlay=self.state.overlay, background=session_background(self.session)
        )
        self.orbit = OrbitCamera.from_view(view)
        self.fields.objects.copy_offset = copy_step(view.look.distance)
        self.fields.status = f"opened {p}" + (
            f"; unsaved edits of the previous scene kept in {kept.resolve()}" if kept else ""
        )
        self.fields.edits_path = str(self.session.default_edits_path(self.fields.output_dir))
        self.fields.confirm_overwrite = None
        editable = isinstance(self.session, EditableScene)
        found = self.session.autosave_path(autosave_dir()) if editable else None
        if found is not None and found.is_file():
            self.fields.edits_path = str(found)
            self.fields.status += f"; autosaved edits of this scene found: Load edits restores them ({found})"

    def shot_camera(self) -> Camera:
        w, h = self.fields.shot_size
        if w > 0 and h > 0:
            return self.orbit.camera(w, h)
        return self.view_camera(1.0, clear_panel=False)  # a screenshot has no panel: centred

    def screenshot_image(self, camera: Camera) -> np.ndarray:
        return self.scene_view.image(self.session, self.state, camera)

    def screenshot_text(self, camera: Camera) -> dict[str, str]:
        look = self.orbit.view.look
        return png_text(
            camera,
            self.session.edit_chunk(),
            self.session.model_name,
            {
                "look": f"{look.azimuth:.6g},{look.elevation:.6g},{look.distance:.6g}",
                "fov": f"{self.orbit.view.fov:.6g}",
                "scene": self.session.source,
                "segmentation": self.state.seg_mode,
            },
        )

    def screenshot_numbered(self) -> Path:
        """A numbered screenshot in the output folder (refused, nothing written, where the scene's guard says so)."""
        cam = self.shot_camera()
        return save_screenshot(
            self.fields.output_dir,
            self.screenshot_image(cam),
            self.screenshot_text(cam),
            lambda p: self.session.guard_output("screenshot", p),
        )

    # ------------------------------------------------------------------ loop
    def run(self, frames: int | None = None, orbit: bool = False, seconds: float | None = None) -> list[float]:
        """Run until the window closes, ``frames`` frames were drawn (each drawn at once: benchmarks,
        tests) or ``seconds`` passed; returns the seconds each frame took (events, UI, render if
        needed, present), not counting the idle wait for input.

        Without ``frames`` the loop draws only when :attr:`redraw` says so, and sleeps in
        ``glfw.wait_events`` in between."""
        times = self.frame_times
        self.background_open = frames is None  # frames drawn at once: a scene opens at once too
        n = 0
        end = None if seconds is None else time.perf_counter() + seconds
        while not glfw.window_should_close(self.window) and (frames is None or n < frames) and not self.stopped:
            if frames is not None:
                glfw.poll_events()
            else:
                now = time.perf_counter()
                if end is not None and now >= end:
                    break
                wait = self.redraw.timeout(now)
                held = self.grace.due_in()  # a press held for a late Ctrl goes on in time, input or not
                if held is not None:
                    wait = held if wait is None else min(wait, held)
                if end is not None:
                    wait = end - now if wait is None else min(wait, end - now)
                if wait is None:
                    glfw.wait_events()  # idle: sleep until input
                elif wait > 0:
                    glfw.wait_events_timeout(wait)
                else:
                    glfw.poll_events()
                if not self.redraw.due(time.perf_counter()) and self.grace.due_in() != 0.0:
                    continue
            t0 = time.perf_counter()
            if orbit:  # as a drag: the camera moves, the frame renders at the moving scale
                self.orbit.turn(ORBIT_STEP)
                self.controls.last_move = t0
            self.frame(show_ui=frames is None or not self.args.no_ui)
            times.append(time.perf_counter() - t0)
            n += 1
        return times

    @property
    def stopped(self) -> bool:
        """A stop signal arrived (:class:`viewer.signals.SignalStop`): the loop ends as when the window closes."""
        return self.stop is not None and self.stop.signum is not None

    def still_frame(self) -> float:
        """Draw the frame that follows a motion once it stopped (full scale); returns its seconds."""
        self.controls.last_move = time.perf_counter() - 2.0 * STILL_AFTER
        t0 = time.perf_counter()
        self.frame(show_ui=not self.args.no_ui)
        return time.perf_counter() - t0


def _x11_sync_function():
    """A call that flushes the window's X11 connection and waits for the server to process it, or False when the
    window is not on X11 (Wayland, macOS, Windows: their swap already waits)."""
    import ctypes.util

    try:
        if glfw.get_platform() != glfw.PLATFORM_X11:
            return False
        display = glfw.get_x11_display()
        name = ctypes.util.find_library("X11")
        if not display or not name:
            return False
        xsync = ctypes.CDLL(name).XSync
    except (AttributeError, OSError, glfw.GLFWError):  # an older glfw, no libX11
        return False
    xsync.argtypes, xsync.restype = [ctypes.c_void_p, ctypes.c_int], ctypes.c_int
    return lambda: xsync(display, 0)


def create_window(size: tuple[int, int], title: str = "ParticleSplat Studio"):
    """A glfw window with a GL 3.3 core context (current) and imgui's native backends."""
    from imgui_bundle.imgui import backends

    check_display()
    reporting, glfw.ERROR_REPORTING = glfw.ERROR_REPORTING, "ignore"  # a failure below is one line, no warnings
    if not glfw.init():
        raise NoDisplay(
            f"cannot open the display {os.environ.get('DISPLAY') or os.environ.get('WAYLAND_DISPLAY')!r}: check "
            "DISPLAY, or run xvfb-run -a particlesplat-viewer"
        )
    glfw.ERROR_REPORTING = reporting
    window = None
    # EGL first: a process that also holds a headless EGL context (tests, benches) cannot make
    # a GLX context current (X error BadAccess); fall back to the platform's native API.
    for api in (glfw.EGL_CONTEXT_API, glfw.NATIVE_CONTEXT_API):
        glfw.default_window_hints()
        glfw.window_hint(glfw.CONTEXT_CREATION_API, api)
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        window = glfw.create_window(size[0], size[1], title, None, None)
        if window:
            break
    if not window:
        glfw.terminate()
        raise RuntimeError("could not create a GL 3.3 core window")
    glfw.make_context_current(window)
    glfw.swap_interval(0)
    imgui.create_context()
    imgui.get_io().set_ini_filename("")
    backends.glfw_init_for_opengl(window_address(window), True)
    backends.opengl3_init("#version 330")
    return window


def destroy_window(window) -> None:
    from imgui_bundle.imgui import backends

    backends.opengl3_shutdown()
    backends.glfw_shutdown()
    imgui.destroy_context()
    glfw.destroy_window(window)
    glfw.terminate()


def run_viewer(args: argparse.Namespace) -> int:
    """The viewer for options :func:`viewer.launch.parse_options` checked: the scene loaded, the window, the loop;
    an exit code."""
    # per-particle decodes are tiny: one torch thread is ~15x faster than two fighting llvmpipe's
    torch.set_num_threads(1)
    if args.screenshot:  # before the scene: never over what the viewer reads, nor into a live run
        guard_outputs([("--screenshot", args.screenshot)], [*source_inputs(args), ("--edits", args.edits)])
    try:
        session = load_session(args)
        view = initial_view(session, args.look, args.fov)
    except (OSError, ValueError, KeyError, IndexError) as e:
        from particlesplat.core.errors import EXIT_USER, one_line

        print(f"particlesplat-viewer: {one_line(e)}", file=sys.stderr)
        return EXIT_USER
    window = create_window(args.size)
    app = None
    stop = SignalStop(glfw.post_empty_event)
    note = ""
    try:
        with stop:
            try:
                app = App(window, session, view, args)
            except UnsupportedGL as e:  # e.g. --compositing fetch on a driver without the extension: a bad argument
                from particlesplat.core.errors import EXIT_USER

                print(f"particlesplat-viewer: {e}", file=sys.stderr)
                return EXIT_USER
            app.stop = stop
            if args.frames is None:
                print(
                    f"particlesplat-viewer: showing {app.session.source or 'the scene'}; screenshots, exports, edits "
                    f"go to {Path(app.fields.output_dir).resolve()} (unsaved edits are kept in {autosave_dir()}); "
                    "close the window or press Ctrl-C here to quit",
                    flush=True,
                )
            code = _run_app(app, args)
    finally:
        try:
            kept = app.keep_unsaved() if app is not None else None  # closing the window (or a signal) loses no edits
        except OutputError as e:  # the autosave folder lies in a scene folder or a live run's folder
            kept, note = None, f"unsaved edits not kept: {e}"
        if kept is not None:
            note = f"unsaved edits kept in {kept.resolve()} (open them with --edits {kept.resolve()})"
        destroy_window(window)
    if stop.signum is not None:  # one line: the signal and where the edits went
        from particlesplat.core.errors import Interrupted

        raise Interrupted(f"{stop.name}{'; ' + note if note else ''}", stop.signum)
    if note:
        print(f"particlesplat-viewer: {note}", file=sys.stderr)
    return code


def _run_app(app: App, args: argparse.Namespace) -> int:
    """The frame loop until the window closes (or ``--frames``), then the benchmark's report; an exit code."""
    times = app.run(args.frames, args.orbit)
    if args.frames is None or app.stopped:
        return 0
    steady = times[1:] if len(times) > 1 else times
    r = app.scene_view.renderer
    moving = f" moving frames at render scale {app.state.moving_scale:g}" if args.orbit else " frames"
    print(
        f"median frame time: {float(np.median(steady)) * 1e3:.2f} ms over {len(steady)}{moving} "
        f"({r.visible_count} Gaussians, {app.framebuffer_size()[0]}x{app.framebuffer_size()[1]}, "
        f"{r.renderer_string}, {r.compositing} compositing)"
    )
    if args.orbit:  # the motion stops: the full-scale frame
        print(f"still frame at full scale: {app.still_frame() * 1e3:.2f} ms")
    if args.screenshot:
        cam = app.view_camera(1.0)
        try:
            path = save_png(args.screenshot, app.screenshot_image(cam), app.screenshot_text(cam))
        except OSError as e:
            print(
                f"particlesplat-viewer: --screenshot {args.screenshot}: cannot write ({e.strerror or e})",
                file=sys.stderr,
            )
            return 2
        print(f"saved {path}")
    return 0
