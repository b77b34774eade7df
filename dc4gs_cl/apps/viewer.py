"""A browser viewer on viser: the picture is rendered by our OpenCL renderer (the trainer's own pipeline) and sent
to each browser tab as its background image; viser supplies the page, the orbit controls and the training
cameras' frustums.

    dc4gs-cl view RUN_FOLDER | FILE.ply [--scene S] [--port P] [--host H] [--iteration N] [--device D]

Frames are rendered in one background thread, one browser tab after another, each at the tab's latest camera
(camera messages that arrive during a render coalesce into one frame): at MOVING_SCALE of the size while the
camera moves, full size once it has been still for SETTLE_SECONDS. The renderer and the device are not
thread-safe: every render holds `Viewer.lock`.

Live training: the trainer calls `publish()` once per iteration from its own thread. With no browser connected
that returns at once; otherwise it renders at most LIVE_FRAMES_PER_SECOND frames per tab, and at most LIVE_SHARE
of the training thread's time for every tab together, in the training thread between two iterations, so training
never shares the device with the viewer's thread.

A client that has the link can still send anything: each message is bounded to MAX_CLIENT_MESSAGE_BYTES before
it is read, and what it sends is checked before any render (client_frame).

viser is optional (the `viewer` extra): this module imports without it and its entry points raise InputError.
"""
from __future__ import annotations

import argparse
import contextlib
import errno
import io
import logging
import math
import secrets
import socket
import sys
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from ..constants import FOV_CLAMP, MAX_ABS_MEAN
from ..errors import InputError
from ..scene.camera import Camera, scene_extent

if TYPE_CHECKING:
    import viser

    from ..render import DeviceGaussians, Renderer
    from ..runtime import Runtime

DEFAULT_PORT = 8080
DEFAULT_HOST = "127.0.0.1"       # this machine only; a connection also needs the printed url's token
MAX_FRAME_SIDE = 640             # px: a still frame is the canvas scaled down to fit this; a GUI slider changes it
FRAME_SIDE_SLIDER = (128, 4096, 32)  # px: that slider's range and step
MOVING_SCALE = 0.5               # frames while the camera moves, relative to a still frame (a quarter the pixels)
SETTLE_SECONDS = 0.25            # a camera unmoved this long gets a full-size frame
LIVE_FRAMES_PER_SECOND = 2.0     # while training: each frame is a render the training waits for
# and at most this share of the training thread's time goes to those renders, every tab together (30 tabs at two
# frames a second each took training from 16.3 to 2.5 iterations a second)
LIVE_SHARE = 0.2
SIGNAL_POLL_SECONDS = 0.2        # serve_forever() wakes this often, so that Ctrl-C stops it
PAUSE_POLL_SECONDS = 0.1         # while training is paused: how often publish() looks at the checkbox
JPEG_QUALITY = 90
MAX_CANVAS_SIDE = 1 << 14        # px: a client's canvas larger than this is no screen (a client sends what it likes)
FRUSTUM_SCALE = 0.05             # frustum depth, as a fraction of the cameras' extent
FRUSTUM_COLOR = (255, 120, 0)
FRUSTUM_LINE_PX = 2.0
THUMBNAIL_WIDTH = 128            # px: training images on the frustums
HOME_FOV_Y = math.radians(60)    # first view of a model without cameras: vertical field of view,
HOME_DIRECTION = np.array([1.0, 1.0, 0.6]) / np.linalg.norm([1.0, 1.0, 0.6])  # direction from the model's centre,
HOME_DISTANCE = 2.5              # and distance in units of its radius (the 90th percentile of the means' distances)
Z_UP = np.array([0.0, 0.0, 1.0])
VIEWER_EXTRA = 'pip install "dc4gs-cl[viewer]"'
# bytes: the largest websocket message a client may send (a camera message is ~250, a GUI update less); viser
# takes up to 50 MB, and 8 clients' camera messages of 45 MB each took the viewer from 246 MB to 5.3 GB
MAX_CLIENT_MESSAGE_BYTES = 64 * 1024
CLIENT_ERROR_EVERY_SECONDS = 10.0   # a client's unreadable messages: one line at most this often, with a count
# viser's warnings that quote what a client sent, whole (a 49 MB log line): our own checks say it once instead
VISER_CLIENT_WARNINGS = (r"\[viser\] .* does not match annotation", r"Queued a .* on a closed connection")


def _viser():
    """The viser module, or InputError saying how to install it."""
    try:
        import viser
        import viser.transforms  # noqa: F401  (the conversions below use it)
    except ImportError:
        raise InputError(None, f"the viewer needs viser, which is not installed: {VIEWER_EXTRA}") from None
    return viser


# cameras ----------------------------------------------------------------------------------------------------
# viser's cameras use our axes (OpenCV: x right, y down, z forward) but store camera-to-world: wxyz is the
# rotation R_world_camera and position the camera centre. Its field of view is vertical, and the background
# image is stretched over the whole canvas.

def view_camera(wxyz, position, fov_y: float, aspect: float, width: int, height: int, name: str = "viewer") -> Camera:
    """Our camera for a viser pose, rendering a width x height image that fills a canvas of this aspect
    (width / height) and vertical field of view: principal point at the centre, fx set by the aspect, so a
    frame whose size rounds the aspect still covers the canvas exactly."""
    R = _viser().transforms.SO3(np.asarray(wxyz, np.float64)).as_matrix().T
    tan_half = math.tan(0.5 * fov_y)
    fy = 0.5 * height / tan_half
    fx = 0.5 * width / (aspect * tan_half)
    return Camera(name, width, height, fx, fy, 0.5 * width, 0.5 * height, R, -R @ np.asarray(position, np.float64))


def client_frame(camera, max_side, scale: float) -> Camera | None:
    """The frame a client's camera asks for (viser's CameraHandle: canvas size, field of view, aspect, pose), at
    most max_side (clamped to the slider's range) a side, times scale; None where the client sent a value that is
    not a finite number in range (a quaternion whose norm overflows included: [1e300, 1e300, 0, 0] gave an all-NaN
    camera): whatever a websocket client sends, the render stays of a bounded size."""
    try:
        canvas = (int(camera.image_width), int(camera.image_height))
        fov, aspect = float(camera.fov), float(camera.aspect)
        wxyz, position = np.asarray(camera.wxyz, np.float64), np.asarray(camera.position, np.float64)
        side = float(max_side)
    except Exception:   # viser's own properties raise on some of them too (aspect: a height of 0)
        return None
    if not (all(1 <= c <= MAX_CANVAS_SIDE for c in canvas) and 0 < fov < math.pi and 1e-3 <= aspect <= 1e3
            and wxyz.shape == (4,) and position.shape == (3,) and np.isfinite(wxyz).all()
            and 0 < np.linalg.norm(wxyz) < math.inf and np.isfinite(position).all()
            and (np.abs(position) <= MAX_ABS_MEAN).all() and math.isfinite(side)):
        return None
    low, high, _ = FRAME_SIDE_SLIDER
    width, height = frame_size(*canvas, int(min(max(side, low), high)), scale)
    return view_camera(wxyz / np.linalg.norm(wxyz), position, fov, aspect, width, height)


def viser_pose(cam: Camera) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(wxyz, position, vertical fov, aspect) of our camera as viser takes them (frustums, client cameras);
    the principal point is taken as centred. A camera with a lens model gets the pinhole that holds its photo's
    whole field (the extent of the image border's rays: a fisheye's frustum is as wide as its photo, not as its
    focal length's pinhole)."""
    wxyz = _viser().transforms.SO3.from_matrix(cam.R.T).wxyz
    tan_x, tan_y = 0.5 * cam.width / cam.fx, 0.5 * cam.height / cam.fy
    if cam.distortion is not None and np.isfinite(cam.distortion.lim).all():
        tan_x, tan_y = (limit / FOV_CLAMP for limit in cam.distortion.lim)
    return wxyz, cam.center, 2 * math.atan(tan_y), tan_x / tan_y


def frame_size(canvas_width: int, canvas_height: int, max_side: int, scale: float = 1.0) -> tuple[int, int]:
    """The frame for a canvas: its size scaled to fit max_side, times scale."""
    s = scale * min(1.0, max_side / max(canvas_width, canvas_height))
    return max(1, round(canvas_width * s)), max(1, round(canvas_height * s))


def _home_view(cameras: list[Camera], points: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(position, look_at, up, vertical fov) of the first view: the first camera's, orbiting about the points'
    centre at its depth; without cameras, the points seen from HOME_DIRECTION."""
    centre, radius = np.zeros(3), 1.0
    if points is not None and len(points):
        centre = np.median(points, axis=0).astype(np.float64)
        radius = float(np.percentile(np.linalg.norm(points - centre, axis=1), 90)) or 1.0
    if not cameras:
        return centre + HOME_DISTANCE * radius * HOME_DIRECTION, centre, Z_UP, HOME_FOV_Y
    up = -np.mean([c.R[1] for c in cameras], axis=0)   # image y points down
    up = up / np.linalg.norm(up) if np.linalg.norm(up) > 1e-6 else Z_UP
    cam = cameras[0]
    forward = cam.R[2]
    depth = float(forward @ (centre - cam.center)) if points is not None else 0.0
    depth = depth if depth > 0 else scene_extent(cameras)
    return cam.center, cam.center + depth * forward, up, viser_pose(cam)[2]


# the server -------------------------------------------------------------------------------------------------

def check_address(host: str, port: int) -> None:
    """InputError naming the flag when the viewer cannot listen on host:port. viser itself would quietly take
    the next free port, and retry forever on an address that is not this machine's."""
    if not 0 <= port <= 65535:
        raise InputError(None, f"--port {port}: not a port number (0 to 65535)")
    try:
        addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as e:
        raise InputError(None, f"--host {host}: {e.strerror}") from None
    for family, kind, proto, _, address in addresses:
        with socket.socket(family, kind, proto) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)   # as asyncio's server: TIME_WAIT is free
            try:
                s.bind(address)
            except OSError as e:
                if e.errno == errno.EADDRINUSE:
                    raise _port_taken(port) from None
                raise InputError(None, f"--host {host}: cannot listen there ({e.strerror})") from None


def _quiet():
    """viser prints its own banner and farewell on stdout; the command says where it serves on stderr."""
    return contextlib.redirect_stdout(io.StringIO())


def _port_taken(port: int) -> InputError:
    return InputError(None, f"--port {port}: already in use (another viewer?); choose another with --port")


@dataclass
class _Model:
    gaussians: "DeviceGaussians"
    sh_degree: int
    iteration: int | None
    live: bool          # the trainer's parameters: rendered only inside publish(), in the training thread


@dataclass
class _View:
    """One browser tab."""
    client: "viser.ClientHandle"
    moved_at: float = -math.inf   # time.monotonic() of its latest camera message
    stale: bool = True            # camera or model changed since its last frame
    sharp: bool = False           # its last frame was full size
    camera: Camera | None = None  # the camera of its last full-size frame


class Viewer:
    def __init__(self, rt: "Runtime", renderer: "Renderer", cameras: list[Camera], port: int = DEFAULT_PORT,
                 host: str = DEFAULT_HOST, background=(0.0, 0.0, 0.0),
                 images: Callable[[Camera], np.ndarray] | None = None, points: np.ndarray | None = None,
                 max_side: int = MAX_FRAME_SIDE):
        """Serve on host:port (port 0: any free port; see `url`). cameras: shown as frustums (click one to look
        through it); images: a camera's (H, W, 3) picture, offered on the frustums; points (N, 3): what the
        first view frames (the model's means); max_side: px, the largest side of a still frame (a GUI slider
        changes it). Nothing is drawn until show() or publish()."""
        viser = _viser()
        check_address(host, port)
        self.rt, self.renderer, self.cameras = rt, renderer, list(cameras)
        self.background = np.asarray(background, np.float32)
        self.lock = threading.Lock()   # the device: held by every render, and by show()
        self._model: _Model | None = None
        self._views: dict[int, _View] = {}
        self._wake = threading.Condition()
        self._closing = threading.Event()
        self._next_live_frame = 0.0
        self._pause = None             # the "Pause training" checkbox, added by the first publish()
        self._last_frame = ""
        self._warned: set[str] = set()
        self._status_lock = threading.Lock()   # status text: set from the render, training and event-loop threads
        self.token = secrets.token_urlsafe(18)   # in the url: a connection without it is refused (_admitted)

        for pattern in VISER_CLIENT_WARNINGS:
            warnings.filterwarnings("ignore", message=pattern, category=UserWarning)
        self._client_errors = _ClientErrors()
        with _quiet():
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if port and self.server.get_port() != port:   # taken between check_address and viser's bind
            with _quiet():
                self.server.stop()
            raise _port_taken(port)
        self.server.gui.configure_theme(show_share_button=False)   # sharing opens a public tunnel
        self.host = host
        position, look_at, up, fov_y = _home_view(self.cameras, points)
        self.server.scene.set_up_direction(up)
        home = self.server.initial_camera
        home.position, home.look_at, home.up, home.fov = position, look_at, up, fov_y
        self._status = self.server.gui.add_markdown("waiting for a model")
        low, high, step = FRAME_SIDE_SLIDER
        self._max_side = self.server.gui.add_slider("Frame size (px)", min=low, max=high, step=step,
                                                    initial_value=max_side)
        self._max_side.on_update(self._frame_size_changed)
        self._add_frustums(images)
        # first of the connection's callbacks, before viser's own (which await): see _admit
        self.server._websock_server._client_connect_cb.insert(0, self._admit)
        logging.getLogger("websockets.server").addFilter(self._client_errors)
        self.server.on_client_connect(self._connected)
        self.server.on_client_disconnect(self._disconnected)
        self._worker = threading.Thread(target=self._serve, name="viewer", daemon=True)
        self._worker.start()

    @property
    def url(self) -> str:
        """The page, with its websocket's address carrying the viewer's token (viser's client connects to the
        address its `websocket` parameter gives)."""
        host = "localhost" if self.host in ("0.0.0.0", "::") else self.host
        address = f"{host}:{self.server.get_port()}"
        return f"http://{address}/?websocket=ws://{address}/{self.token}"

    def __enter__(self) -> "Viewer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._closing.set()
        with self._wake:
            self._wake.notify_all()
        self._worker.join()
        with _quiet():
            self.server.stop()
        logging.getLogger("websockets.server").removeFilter(self._client_errors)

    def serve_forever(self) -> None:
        """Block until close() (from another thread) or Ctrl-C, whose KeyboardInterrupt propagates."""
        while not self._closing.wait(SIGNAL_POLL_SECONDS):   # SIGINT may reach another thread: Python acts on it
            pass                                              # only when the main thread wakes

    # what is shown ----------------------------------------------------------------------------------------
    def show(self, gaussians: "DeviceGaussians", sh_degree: int, iteration: int | None = None) -> None:
        """Show these Gaussians from now on, rendered in the viewer's thread: from here on, other device work on
        the same Runtime must hold `lock` (the trainer's publish() needs none)."""
        with self.lock:
            self._model = _Model(gaussians, sh_degree, iteration, live=False)
        if self._pause is not None:
            self._pause.remove()
            self._pause = None
        self._model_changed()

    def publish(self, gaussians: "DeviceGaussians", sh_degree: int, iteration: int,
                stopping: Callable[[], bool] | None = None) -> None:
        """The trainer's hook, called after each iteration from the training thread. Nobody watching: returns at
        once. Otherwise renders every tab, at most LIVE_FRAMES_PER_SECOND times a second and at most LIVE_SHARE of
        the thread's time in all, here, between two iterations; and while "Pause training" is ticked, keeps
        rendering camera moves here until it is unticked, the last tab closes, or stopping() says the run is being
        stopped (Ctrl-C)."""
        if not self._views:
            return
        with self.lock:
            self._model = _Model(gaussians, sh_degree, iteration, live=True)
        if self._pause is None:
            self._pause = self.server.gui.add_checkbox("Pause training", initial_value=False)
        now = time.monotonic()
        if now >= self._next_live_frame:
            self._model_changed()
            self._render_due(in_training=True)
            spent = time.monotonic() - now   # the next renders wait until this was LIVE_SHARE of the time since
            self._next_live_frame = now + max(1.0 / LIVE_FRAMES_PER_SECOND, spent / LIVE_SHARE)
        while (self._pause.value and self._views and not self._closing.is_set()
               and not (stopping is not None and stopping())):
            self._render_due(in_training=True)
            with self._wake:
                self._wake.wait(PAUSE_POLL_SECONDS)

    def frame_cameras(self) -> dict[int, Camera]:
        """Each tab whose picture is up to date, full size: the camera it was rendered from (by client id)."""
        return {k: v.camera for k, v in list(self._views.items()) if v.sharp and not v.stale and v.camera}

    def _model_changed(self) -> None:
        for view in list(self._views.values()):
            view.stale = True
        self._update_status()
        self._notify()

    def _update_status(self) -> None:
        model = self._model
        if model is None:
            return
        text = f"**{model.gaussians.n:,} Gaussians**, SH degree {model.sh_degree}"
        if model.iteration is not None:
            text += f", iteration {model.iteration:,}"
        with self._status_lock:
            self._status.content = text + self._last_frame

    # frustums ---------------------------------------------------------------------------------------------
    def _add_frustums(self, images: Callable[[Camera], np.ndarray] | None) -> None:
        if not self.cameras:
            return
        scale = FRUSTUM_SCALE * scene_extent(self.cameras)
        frustums = []
        for i, cam in enumerate(self.cameras):
            wxyz, position, fov_y, aspect = viser_pose(cam)
            frustum = self.server.scene.add_camera_frustum(
                f"/cameras/{i}", fov=fov_y, aspect=aspect, scale=scale, wxyz=wxyz, position=position,
                color=FRUSTUM_COLOR, thickness=FRUSTUM_LINE_PX, thickness_units="screen")
            frustum.on_click(lambda event, cam=cam: self._look_through(event.client, cam))
            frustums.append(frustum)
        shown = self.server.gui.add_checkbox("Training cameras", initial_value=True)

        @shown.on_update
        def _(_) -> None:
            for frustum in frustums:
                frustum.visible = shown.value
        if images is None:
            return
        from ..scene.images import resize   # OpenImageIO: only where a scene's images are shown
        pictures = self.server.gui.add_checkbox("Training images", initial_value=False)

        @pictures.on_update
        def _(_) -> None:   # read on first use: a large scene's images take a while
            for cam, frustum in zip(self.cameras, frustums):
                height = max(1, round(THUMBNAIL_WIDTH * cam.height / cam.width))
                frustum.image = resize(images(cam), THUMBNAIL_WIDTH, height) if pictures.value else None

    @staticmethod
    def _look_through(client: "viser.ClientHandle", cam: Camera) -> None:
        wxyz, position, fov_y, _ = viser_pose(cam)
        with client.atomic():
            client.camera.wxyz = wxyz
            client.camera.position = position
            client.camera.fov = fov_y

    # clients and frames -----------------------------------------------------------------------------------
    # The callbacks are coroutines: viser runs them on its event loop in order, so a tab's first camera
    # message already finds its view. They only mark what to draw and wake the thread.
    async def _connected(self, client: "viser.ClientHandle") -> None:
        self._views[client.client_id] = view = _View(client)

        @client.camera.on_update
        async def _(_) -> None:
            view.moved_at, view.stale = time.monotonic(), True
            self._notify()
        self._notify()

    async def _admit(self, connection: "viser.infra.WebsockClientConnection") -> None:
        """A new websocket stays only if its path holds the viewer's token (the printed url carries it, as Jupyter's
        does) and a browser's Origin is the page's own (its Host), so that neither another site open in the
        browser nor another local user without the link can connect. Run by viser's websocket server on each
        connection before it sends the client anything or reads a message from it; a refused one is closed there.
        (viser keeps each connection's handshake on that server, in private attributes: viser is pinned.) The first
        of the connection's callbacks, it also bounds the messages the client may send, before any is read past
        its first frame's header (nothing awaits between the handshake and here)."""
        websocket = self.server._websock_server._live_connections.get(connection.client_id)
        if websocket is not None:   # a larger message closes the connection (1009) unparsed
            websocket.protocol.max_message_size = MAX_CLIENT_MESSAGE_BYTES
        request = getattr(websocket, "request", None)
        if request is not None:
            origin, host = request.headers.get("Origin"), request.headers.get("Host")
            if (request.path.split("?")[0] == f"/{self.token}"
                    and (origin is None or origin in (f"http://{host}", f"https://{host}"))):
                return
        self._warn_once("refused a connection without this viewer's link (its token) or from another site's page")
        if websocket is not None:
            await websocket.close(1008, "not this viewer's link")

    async def _frame_size_changed(self, _event) -> None:
        """A client's frame-size slider value back within the slider's range, whatever it sent (viser casts it to the
        slider's int: 1e30 became an int that no message can carry, and every connection after it failed), written
        back before anything awaits so that every tab and late joiner gets the bounded value; then new frames."""
        value, (low, high, _) = self._max_side.value, FRAME_SIDE_SLIDER
        finite = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        bounded = int(min(max(value, low), high)) if finite else MAX_FRAME_SIDE
        if bounded != value:
            self._max_side.value = bounded
        self._model_changed()

    async def _disconnected(self, client: "viser.ClientHandle") -> None:
        self._views.pop(client.client_id, None)
        self._notify()

    def _notify(self) -> None:
        with self._wake:
            self._wake.notify_all()

    def _serve(self) -> None:
        while not self._closing.is_set():
            with self._wake:
                self._wake.wait(self._next_wait())
            if not self._closing.is_set():
                self._render_due(in_training=False)

    def _next_wait(self) -> float | None:
        """Seconds until a tab needs a frame from this thread (None: until woken)."""
        model = self._model
        if model is None or model.live:
            return None
        now = time.monotonic()
        waits = [0.0 if v.stale else v.moved_at + SETTLE_SECONDS - now
                 for v in list(self._views.values()) if v.stale or not v.sharp]
        return max(0.0, min(waits)) if waits else None

    def _render_due(self, in_training: bool) -> None:
        now = time.monotonic()
        for view in list(self._views.values()):
            moving = now - view.moved_at < SETTLE_SECONDS
            if view.stale:
                self._send_frame(view, MOVING_SCALE if moving else 1.0, in_training)
            elif not view.sharp and not moving:
                self._send_frame(view, 1.0, in_training)

    def _send_frame(self, view: _View, scale: float, in_training: bool) -> None:
        with self.lock:
            model = self._model
            if model is None or model.live != in_training:
                return
            view.stale = False   # before reading the camera: a message arriving during the render marks it again
            cam = client_frame(view.client.camera, self._max_side.value, scale)
            if cam is None:
                self._warn_once("a client's camera or frame size is not a finite number in range: no frame for it")
                return
            start = time.perf_counter()
            try:
                image = self.renderer.render(model.gaussians, cam, model.sh_degree, self.background).image(self.rt)
            except Exception as e:   # the viewer's failure stays the viewer's: training (the caller) goes on
                self._warn_once(f"frame {cam.width}x{cam.height} not rendered ({type(e).__name__}: "
                                f"{' '.join(str(e).split())[:200]})")
                return
            seconds = time.perf_counter() - start
        view.client.scene.set_background_image(image, format="jpeg", jpeg_quality=JPEG_QUALITY)
        view.sharp = scale == 1.0
        view.camera = cam if view.sharp else None
        self._last_frame = f"<br/>frame {cam.width}x{cam.height}: {seconds * 1e3:.0f} ms"
        self._update_status()

    def _warn_once(self, message: str) -> None:
        """A viewer problem, on stderr the first time each is met (a client can repeat it at every frame)."""
        if message not in self._warned:
            self._warned.add(message)
            print(f"viewer: {message}", file=sys.stderr)


class _ClientErrors(logging.Filter):
    """websockets' log of a connection whose handler failed: a client's message that is no message (viser's
    decoder raises, and the connection closes). A traceback for every such message would let any client fill
    the log: instead one line on stderr at most every CLIENT_ERROR_EVERY_SECONDS, counting those in between."""

    def __init__(self):
        super().__init__()
        self.next_line, self.unsaid = 0.0, 0

    def filter(self, record: logging.LogRecord) -> bool:
        if record.exc_info is None:
            return True
        self.unsaid += 1
        now = time.monotonic()
        if now >= self.next_line:
            error = record.exc_info[1]
            more = f"; {self.unsaid - 1:,} more since the last such line" if self.unsaid > 1 else ""
            print(f"viewer: closed a connection whose message could not be read ({type(error).__name__}: "
                  f"{' '.join(str(error).split())[:120]}){more}", file=sys.stderr)
            self.next_line, self.unsaid = now + CLIENT_ERROR_EVERY_SECONDS, 0
        return False


# the command ------------------------------------------------------------------------------------------------

def add_arguments(p: argparse.ArgumentParser) -> None:
    """The `view` command's arguments (cli.py adds --antialiased and --device)."""
    p.add_argument("source", type=Path, help="a training output folder (its model and training cameras) or a model "
                                             "file: a 3DGS PLY or any format `export` writes (.splat, .spz, "
                                             ".compressed.ply)")
    p.add_argument("--scene", default=None,
                   help="the scene whose training cameras to show (default: a run folder's own; none for a PLY)")
    p.add_argument("--iteration", type=int, default=None,
                   help="with a run folder: which saved iteration (default: the last)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port to serve on ({DEFAULT_PORT})")
    p.add_argument("--host", default=DEFAULT_HOST,
                   help=f"address to listen on ({DEFAULT_HOST}: this machine only; 0.0.0.0: every network, and "
                        "anyone there can see the model)")
    p.add_argument("--white-background", action="store_true",
                   help="render onto white (Blender scenes; a run folder says for itself)")


def cmd_view(args) -> int:
    _viser()
    check_address(args.host, args.port)   # before loading: a large model takes a while
    from ..render import DeviceGaussians, Renderer, RenderOptions
    from ..runtime import Runtime, describe
    from ..scene.loader import load_scene
    from .model_source import ModelSource

    path = Path(args.source)
    if not path.exists():
        raise InputError(path, "not found: expected a training output folder or a model file")
    if args.iteration is not None and not path.is_dir():
        raise InputError(None, "--iteration needs a training output folder")
    source = ModelSource.of_path(path, args.iteration)
    if source.run is not None:
        scene = source.run.load_scene(source.cfg, scene=args.scene, white_background=args.white_background)
    else:
        scene = load_scene(args.scene, white_background=args.white_background) if args.scene else None
    background = scene.background if scene else np.full(3, 1.0 if args.white_background else 0.0, np.float32)
    model = source.model
    rt = Runtime(args.device)
    renderer = Renderer(rt, options=RenderOptions.of_model(args.antialiased, source.antialiased))
    with Viewer(rt, renderer, scene.train if scene else [], port=args.port, host=args.host,
                background=background, images=scene.image if scene else None, points=model.means) as viewer:
        viewer.show(DeviceGaussians(rt, model), model.sh_degree, source.iteration)
        print(f"device: {describe(rt.device)}; {len(model):,} Gaussians (SH degree {model.sh_degree})"
              f"{f', {len(scene.train)} training cameras' if scene else ''}\nviewer: {viewer.url} (Ctrl-C to stop)",
              file=sys.stderr)
        viewer.serve_forever()
    return 0
