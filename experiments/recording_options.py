"""What a rerun :class:`~experiments.recording.Recorder` is asked to do, apart from the run itself:
its drawing options (:class:`RecorderOptions`: particles drawn, trail length, region probability,
sizes in metres, batch size), where it streams live (:class:`LiveView`: a served gRPC stream and web
viewer, or a running viewer; :func:`grpc_url` parses a viewer's address, :func:`check_port_free`
tests a TCP port before rerun's server thread would fail silently on it) and the viewer's default
layout (:func:`default_blueprint`)."""
from __future__ import annotations

from dataclasses import dataclass

import rerun.blueprint as rrb


@dataclass(frozen=True)
class RecorderOptions:
    """What a :class:`~experiments.recording.Recorder` logs per estimator update.

    ``max_particles_logged``: particles drawn per object (the heaviest ones when K is larger; 0 logs no
    particle cloud). ``trail_length``: consensus positions kept per trajectory. ``region``: the
    uncertainty ellipsoids are each position's region of this probability under its own distribution
    (a Student-t's is wider than a Gaussian's of the same covariance:
    :meth:`~estimator.belief.ObjectBelief.region`). ``particle_radius``,
    ``box_line_radius``: drawing sizes in metres. ``floor_half_size``: half extent (m) of the floor
    square drawn at z = 0. ``batch``: drawings and plot values are buffered and written as columns
    every this many ``log_*`` calls; :meth:`~experiments.recording.Recorder.flush` and
    :meth:`~experiments.recording.Recorder.close` write the rest.
    """

    max_particles_logged: int = 256
    trail_length: int = 200
    region: float = 0.9
    particle_radius: float = 0.003
    box_line_radius: float = 0.001
    floor_half_size: float = 1.5
    batch: int = 32

    def __post_init__(self):
        if self.max_particles_logged < 0:
            raise ValueError(f"max_particles_logged must be >= 0, got {self.max_particles_logged}")
        if self.trail_length < 2:
            raise ValueError(f"trail_length must be >= 2, got {self.trail_length}")
        if self.batch < 1:
            raise ValueError(f"batch must be >= 1, got {self.batch}")
        if not 0 < self.region < 1:
            raise ValueError(f"region must be in (0, 1), got {self.region}")


@dataclass(frozen=True)
class LiveView:
    """Where a :class:`~experiments.recording.Recorder` streams besides (or instead of) its file.

    ``serve``: host a gRPC server on ``bind``:``grpc_port`` that viewers connect to
    (``rerun rerun+http://HOST:PORT/proxy``); it keeps up to ``memory_limit`` of the stream for
    viewers that connect late (the oldest data is dropped beyond it, the static scene never), so
    that an endless run does not grow without bound. ``web_port``: also serve rerun's web viewer
    over HTTP on that port, connected to the server (None: none). ``connect``: the gRPC URL of a
    running viewer or server to send to (``rerun+http://HOST:PORT/proxy``, :func:`grpc_url`).
    """

    serve: bool = False
    grpc_port: int = 9876
    web_port: int | None = 9090
    bind: str = "0.0.0.0"
    connect: str | None = None
    memory_limit: str = "256MiB"

    def __post_init__(self):
        if not (self.serve or self.connect):
            raise ValueError("a live view serves (serve=True) or connects to a viewer (connect=URL)")
        for name in ("grpc_port", "web_port"):
            port = getattr(self, name)
            if port is not None and not 0 < port < 65536:
                raise ValueError(f"{name} must be a TCP port (1-65535), got {port}")

    def viewer_url(self, host: str = "127.0.0.1") -> str | None:
        """The address to open in a browser (the web viewer, connected to the served stream), with
        ``host`` the machine's name as the browser reaches it; None without a web viewer."""
        if not self.serve or self.web_port is None:
            return None
        from urllib.parse import quote
        return f"http://{host}:{self.web_port}/?url=" + quote(self.grpc_uri(host), safe="")

    def grpc_uri(self, host: str = "127.0.0.1") -> str:
        """The served stream's gRPC URL, as a native viewer opens it (``rerun URL``)."""
        return f"rerun+http://{host}:{self.grpc_port}/proxy"


def grpc_url(address: str) -> str:
    """A viewer's gRPC URL from ``HOST:PORT``, ``PORT`` or a full ``rerun+http://HOST:PORT/proxy``
    (``rerun://`` and ``rerun+https://`` too). Raises ValueError for anything else."""
    a = address.strip()
    if a.startswith(("rerun://", "rerun+http://", "rerun+https://")):
        if not a.rstrip("/").endswith("/proxy"):
            a = a.rstrip("/") + "/proxy"
        return a
    host, sep, port = a.rpartition(":")
    if not sep:
        host, port = "127.0.0.1", a
    if not port.isdigit() or not 0 < int(port) < 65536 or (sep and not host):
        raise ValueError(f"expected HOST:PORT, PORT or rerun+http://HOST:PORT/proxy, got {address!r}")
    return f"rerun+http://{host}:{int(port)}/proxy"


def check_port_free(bind: str, port: int, what: str) -> None:
    """Raise ValueError when ``port`` cannot be listened on at ``bind`` (rerun's gRPC server would
    fail silently in a thread of its own)."""
    import socket
    with socket.socket(socket.AF_INET6 if ":" in bind else socket.AF_INET) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((bind, port))
        except OSError as exc:
            raise ValueError(f"{what}: cannot listen on {bind}:{port}: {exc.strerror or exc}") from None


def default_blueprint() -> rrb.Blueprint:
    """The default layout: the 3D scene on the left; ESS, probabilities (tabs) and the text log on the
    right."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="Scene", origin="/world"),
            rrb.Vertical(
                rrb.TimeSeriesView(name="ESS", origin="/plots/ess"),
                rrb.Tabs(
                    rrb.TimeSeriesView(name="P(plausible)", origin="/plots/p_plausible"),
                    rrb.TimeSeriesView(name="P(held)", origin="/plots",
                                       contents=["$origin/p_held/**", "$origin/truth/held/**"]),
                    rrb.TimeSeriesView(name="Relations", origin="/plots",
                                       contents=["$origin/relations/**", "$origin/truth/relations/**"]),
                ),
                rrb.TextLogView(name="Facts and events", origin="/log"),
                row_shares=[1, 2, 2],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )

