"""Rerun recordings (``.rrd``) of what the estimator perceives, believes and what was true.

A :class:`Recorder` owns its own :class:`rerun.RecordingStream` (application id ``scene-estimator``,
a fresh recording id per instance) that writes to one file, or streams live
(:class:`~experiments.recording_options.LiveView`: a gRPC server that rerun's viewers, native or in
a browser, connect to, or a connection to a running viewer), or both; it never touches rerun's
global recording, so two recorders in one process keep their data apart. Open the file with
``rerun run.rrd``. Time is the stream's ``t`` (seconds), on the timeline
:data:`~experiments.recording_draw.TIMELINE`. Its options, live view and default layout are in
:mod:`experiments.recording_options`, its colours and column buffers in
:mod:`experiments.recording_draw`, the geometry it draws in :mod:`experiments.recording_geometry`.

Entity paths (object ids are escaped as entity path parts; M objects)::

    world/scene/<id>                    static: geometry of the static objects (URDF visual meshes,
                                        primitives), the floor and the camera frustum
    world/perceived/objects             pink boxes: the detections of the last frame
    world/perceived/hands               pink points: tracked hands
    world/belief/consensus              green boxes: consensus poses of the dynamic objects
    world/belief/uncertainty            green ellipsoids: each position's 90 % region
    world/belief/particles/<id>         the particle cloud of each object, dark = heavy
    world/belief/hypotheses             orange points labelled "cup: isOnTop table 0.81"
    world/belief/trajectories           line strips of the consensus positions so far
    world/truth/objects, world/truth/hands   grey wireframe boxes and points: the ground truth
    plots/ess                           effective sample size
    plots/p_plausible/<id>, plots/p_held/<id>, plots/relations/<predicate>/<subject>/<object>
    plots/truth/held/<id>, plots/truth/relations/<predicate>/<subject>/<object>   0 / 1
    log/events                          per-update event probabilities (Pick / Place / Release / Push)
    log/timeline                        facts (begin / end) and events of the final timeline
    log/truth                           true events

Rerun 0.41 draws no dashed lines: the truth is drawn as grey wireframe boxes (the static scene is
solid, the perceived boxes pink, the consensus green).
"""
from __future__ import annotations

import os
import uuid
from collections import deque
from dataclasses import replace
from pathlib import Path

import numpy as np
import rerun as rr
from rerun.components import FillMode

from estimator.belief import Belief
from estimator.observations import Frame
from experiments.recording_draw import (
    FLOOR_GREY,
    GREEN,
    GREEN_SHADE,
    ORANGE,
    PINK,
    TIMELINE,
    TRUTH_GREY,
    Rows,
    packed,
    path,
    weight_colors,
)
from experiments.recording_geometry import boxes_at, covariance_ellipsoids, local_boxes, static_geometry
from experiments.recording_options import LiveView, RecorderOptions, check_port_free, default_blueprint, grpc_url
from physics.scene import Scene
from physics.world import World

APPLICATION_ID = "scene-estimator"


class Recorder:
    """Write a rerun recording of a run to ``path`` (an ``.rrd`` file, created or overwritten), and,
    with ``live``, stream it to viewers as it is made (:class:`~experiments.recording_options.LiveView`;
    ``path`` may then be None).

    The static scene (geometry of static objects, floor, camera frustum) and a default layout (3D view,
    plots, text log) are written at construction. Call :meth:`log_frame`, :meth:`log_belief`,
    :meth:`log_truth` and :meth:`log_timeline` in any order; :meth:`close` (or leaving the ``with``
    block) writes what is buffered and closes the file.

    Per-update drawings and plot values are buffered and written as columns every
    ``options.batch`` calls (one write per entity instead of one per value: the logging cost per
    update is a few numpy operations); text entries are written at once.

    Args:
        path: the ``.rrd`` file (None: no file; ``live`` needed then).
        scene: the scene the run is about (its geometry gives every box's size).
        max_particles_logged: particles drawn per object and update (the heaviest ones; 0: none).
        options: every other drawing option; ``max_particles_logged``, when given, overrides its own.
        live: stream to viewers too (a gRPC server and a web viewer, or a running viewer); a port that
            cannot be listened on is a ValueError. :attr:`viewer_url` is then the address to open.
    """

    def __init__(self, path: str | os.PathLike | None, scene: Scene, *, max_particles_logged: int | None = None,
                 options: RecorderOptions | None = None, live: LiveView | None = None):
        opts = options or RecorderOptions()
        if max_particles_logged is not None and max_particles_logged != opts.max_particles_logged:
            opts = replace(opts, max_particles_logged=max_particles_logged)
        self.options = opts
        if path is None and live is None:
            raise ValueError("a recorder needs a file (path) or a live view (live)")
        self.path = None if path is None else Path(path)
        self.live = live
        self.viewer_url: str | None = None
        self.scene = scene
        self.recording_id = str(uuid.uuid4())
        self._dynamic = [o.id for o in scene.objects if not o.static]
        self._trails: dict[str, deque] = {oid: deque(maxlen=opts.trail_length) for oid in self._dynamic}
        self._relations_seen: set[tuple[str, str, str]] = set()
        self._truth_relations_seen: set[tuple[str, str, str]] = set()
        self._rows: dict[str, Rows] = {}
        self._pending = 0
        self._paths: dict[tuple[str, ...], str] = {}
        self._closed = True
        with World(scene) as world:
            statics = static_geometry(world, scene)
            self._local = local_boxes(world)
        if live is not None and live.serve:
            check_port_free(live.bind, live.grpc_port, "the live view's gRPC server")
            if live.web_port is not None:
                check_port_free(live.bind, live.web_port, "the live view's web viewer")
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self.stream = rr.RecordingStream(APPLICATION_ID, recording_id=self.recording_id)
        self._closed = False
        try:
            self.stream.set_log_time_enabled(False)
            self.stream.set_log_tick_enabled(False)
            self.stream.set_sinks(*self._sinks(), default_blueprint=default_blueprint())
            self.stream.send_recording_name(self.path.stem if self.path is not None else scene.name)
            self._log_static(statics)
            if live is not None and live.serve and live.web_port is not None:
                try:  # rerun's web viewer: one per process, up until the process ends
                    rr.serve_web_viewer(web_port=live.web_port, open_browser=False, connect_to=live.grpc_uri())
                except RuntimeError as exc:
                    raise ValueError(f"the live view's web viewer: {exc}") from None
                self.viewer_url = live.viewer_url()
        except BaseException:
            self.close()
            raise

    def _sinks(self) -> list:
        """rerun sinks: the file, the served gRPC stream, the running viewer (as asked)."""
        sinks = [] if self.path is None else [rr.FileSink(str(self.path))]
        live = self.live
        if live is not None and live.serve:
            sinks.append(rr.GrpcServerSink(live.bind, live.grpc_port, server_memory_limit=live.memory_limit))
        if live is not None and live.connect:
            sinks.append(rr.GrpcSink(grpc_url(live.connect)))
        return sinks

    # -- life cycle ---------------------------------------------------------------------------------
    def flush(self) -> None:
        """Write everything buffered (the file then holds the whole run so far)."""
        for entity, rows in self._rows.items():
            rows.write(self.stream, entity)
        self._pending = 0
        self.stream.flush()

    def close(self) -> None:
        """Write what is buffered and close the file. Safe to call twice."""
        if self._closed:
            return
        try:
            self.flush()
        finally:
            self._closed = True
            self.stream.disconnect()

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _start(self, t: float) -> float:
        if self._closed:
            raise RuntimeError(f"the recorder of {self.path or 'the live view'} is closed")
        return float(t)

    def _done(self) -> None:
        self._pending += 1
        if self._pending >= self.options.batch:
            self.flush()

    def _rows_of(self, entity: str, archetype, **mono) -> Rows:
        rows = self._rows.get(entity)
        if rows is None:
            rows = self._rows[entity] = Rows(archetype, **mono)
        return rows

    def _text(self, entity: str, t: float, text: str, level: str) -> None:
        self.stream.set_time(TIMELINE, duration=float(t))
        self.stream.log(entity, rr.TextLog(text, level=level))

    def _path(self, *parts: str) -> str:
        p = self._paths.get(parts)
        if p is None:
            p = self._paths[parts] = path(*parts)
        return p

    def _scalar(self, entity: str, t: float, value: float) -> None:
        self._rows_of(entity, rr.Scalars).add(t, 1, scalars=[float(value)])

    # -- static scene -------------------------------------------------------------------------------
    def _log_static(self, statics: list[tuple[str, object]]) -> None:
        log = self.stream.log
        log("/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for oid, archetype in statics:
            log(path("world", "scene", oid), archetype, static=True)
        if self.scene.floor:
            h = self.options.floor_half_size
            log("/world/scene/floor", rr.Boxes3D(half_sizes=[[h, h, 0.0005]], centers=[[0, 0, -0.0005]],
                                                 colors=[FLOOR_GREY], fill_mode=FillMode.Solid), static=True)
        cam = self.scene.camera
        if cam is not None:
            forward = np.subtract(cam.target, cam.position)
            forward = forward / np.linalg.norm(forward)
            right = np.cross(forward, cam.up)
            right = right / np.linalg.norm(right)
            down = np.cross(forward, right)
            log("/world/scene/camera", rr.Transform3D(translation=cam.position,
                                                      mat3x3=np.column_stack([right, down, forward])), static=True)
            log("/world/scene/camera", rr.Pinhole(fov_y=np.radians(cam.fov_deg), aspect_ratio=cam.aspect,
                                                  camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.2),
                static=True)

    # -- shared drawings ----------------------------------------------------------------------------
    def _boxes(self, entity: str, t: float, ids: list[str], positions, orientations, color, fill_mode,
               labels: list[str] | None = None) -> None:
        n = len(ids)
        centers, half = boxes_at([self._local[o] for o in ids], positions, orientations)
        self._rows_of(entity, rr.Boxes3D, fill_mode=fill_mode).add(
            t, n, half_sizes=half, centers=centers, quaternions=np.asarray(orientations, float).reshape(-1, 4),
            colors=np.full(n, packed(color)), radii=np.full(n, self.options.box_line_radius),
            labels=list(labels if labels is not None else ids))

    def _hands(self, entity: str, t: float, hands: dict, color) -> None:
        n = len(hands)
        pos = np.array([np.asarray(v, float) for v in hands.values()]).reshape(-1, 3)
        self._rows_of(entity, rr.Points3D).add(t, n, positions=pos, radii=np.full(n, 0.02),
                                               colors=np.full(n, packed(color)), labels=list(hands))

    def _relations(self, root: tuple[str, ...], t: float, relations: list[dict], seen: set) -> None:
        """One series per relation ever listed; a relation that stops being listed is logged as 0."""
        now = {(r["predicate"], r["subject"], r["object"]): float(r.get("p", 1.0)) for r in relations}
        seen.update(now)
        for key in seen:
            self._scalar(self._path(*root, "relations", *key), t, now.get(key, 0.0))

    # -- perception ---------------------------------------------------------------------------------
    def log_frame(self, frame: Frame) -> None:
        """Log a perception frame at ``frame.t``: detections as pink boxes (identity orientation when
        not measured), tracked hands as pink points. An empty frame shows none."""
        t = self._start(frame.t)
        ids = [oid for oid in frame.objects if oid in self._local]
        pos = np.array([frame.objects[o].position for o in ids]).reshape(-1, 3)
        orn = np.array([frame.objects[o].orientation if frame.objects[o].orientation is not None
                        else (0.0, 0.0, 0.0, 1.0) for o in ids]).reshape(-1, 4)
        self._boxes("/world/perceived/objects", t, ids, pos, orn, PINK, FillMode.MajorWireframe)
        self._hands("/world/perceived/hands", t, frame.hands, PINK)
        self._done()

    # -- belief -------------------------------------------------------------------------------------
    def log_belief(self, belief: Belief) -> None:
        """Log a belief at ``belief.t``: consensus boxes, uncertainty ellipsoids, particle clouds,
        hypotheses, trajectories, plots (ESS, P(plausible), P(held), relation probabilities) and the
        update's events. Static objects are left out (they are in the static scene)."""
        t = self._start(belief.t)
        opts = self.options
        ids = [oid for oid in self._dynamic if oid in belief.objects]
        obs = [belief.objects[o] for o in ids]
        n = len(ids)
        pos = np.array([b.position for b in obs], float).reshape(-1, 3)
        orn = np.array([b.orientation for b in obs], float).reshape(-1, 4)
        self._boxes("/world/belief/consensus", t, ids, pos, orn, GREEN, FillMode.MajorWireframe)
        r2 = np.array([b.region(opts.region) for b in obs], float)  # squared Mahalanobis radii
        half, quat = covariance_ellipsoids(np.array([b.position_cov for b in obs], float).reshape(-1, 3, 3)
                                           * r2[:, None, None], 1.0)
        self._rows_of("/world/belief/uncertainty", rr.Ellipsoids3D,
                      fill_mode=FillMode.TransparentFillMajorWireframe).add(
            t, n, half_sizes=half, quaternions=quat, centers=pos, colors=np.full(n, packed(GREEN_SHADE)))
        self._particles(belief, t, ids)
        hyps = [(oid, h) for oid, b in zip(ids, obs) for h in b.hypotheses]
        self._rows_of("/world/belief/hypotheses", rr.Points3D).add(
            t, len(hyps), positions=np.array([h.position for _, h in hyps], float).reshape(-1, 3),
            radii=np.array([0.004 + 0.012 * float(h.p) for _, h in hyps]),
            colors=np.full(len(hyps), packed(ORANGE)),
            labels=[f"{oid}: {h.relation if h.support is None else f'{h.relation} {h.support}'} {h.p:.2f}"
                    for oid, h in hyps])
        for oid, p in zip(ids, pos):
            self._trails[oid].append(p)
        strips = [np.array(self._trails[o]) for o in ids if len(self._trails[o]) >= 2]
        self._rows_of("/world/belief/trajectories", rr.LineStrips3D).add(
            t, len(strips), strips=strips, colors=np.full(len(strips), packed(GREEN)),
            radii=np.full(len(strips), 0.0015))
        self._scalar("/plots/ess", t, belief.ess)
        for oid, b in zip(ids, obs):
            self._scalar(self._path("plots", "p_plausible", oid), t, b.p_plausible)
            self._scalar(self._path("plots", "p_held", oid), t, b.p_held)
        self._relations(("plots",), t, belief.relations, self._relations_seen)
        if belief.events:
            self._text("/log/events", t, "; ".join(f"{e.action} {e.subject} p={e.p:.2f}" for e in belief.events),
                       "INFO")
        self._done()

    def _particles(self, belief: Belief, t: float, ids: list[str]) -> None:
        """Each object's particle positions, the ``max_particles_logged`` heaviest, shaded by weight."""
        n = self.options.max_particles_logged
        if n == 0 or belief.particles is None or belief.weights is None:
            return
        w = np.asarray(belief.weights, float)
        sel = np.argsort(-w, kind="stable")[:n] if len(w) > n else np.arange(len(w))
        rgba = weight_colors(w[sel]).astype(np.uint32)
        colors = (rgba[:, 0] << 24) | (rgba[:, 1] << 16) | (rgba[:, 2] << 8) | rgba[:, 3]
        radii = np.full(len(sel), self.options.particle_radius)
        columns = {oid: m for m, oid in enumerate(belief.object_ids)}
        for oid in self._dynamic:
            m = columns.get(oid)
            rows = self._rows_of(self._path("world", "belief", "particles", oid), rr.Points3D)
            if oid in ids and m is not None:
                rows.add(t, len(sel), positions=belief.particles[sel, m, :3], colors=colors, radii=radii)
            else:
                rows.add(t, 0, positions=np.zeros((0, 3)), colors=colors[:0], radii=radii[:0])

    # -- ground truth and timeline ------------------------------------------------------------------
    def log_truth(self, row: dict) -> None:
        """Log one ground-truth row of the simulator (``truth.jsonl``) at ``row["t"]``: true poses of
        the dynamic objects (grey wireframe boxes, labelled ``(hidden)`` / ``(held)``), true hands,
        true held flags and relations as 0 / 1 plots, and true events in ``log/truth``."""
        t = self._start(row["t"])
        objects = row.get("objects", {})
        ids = [oid for oid in self._dynamic if oid in objects]
        pos = np.array([objects[o]["position"] for o in ids], float).reshape(-1, 3)
        orn = np.array([objects[o]["orientation"] for o in ids], float).reshape(-1, 4)
        labels = [oid + ("" if objects[oid].get("visible", True) else " (hidden)")
                  + (" (held)" if objects[oid].get("held") else "") for oid in ids]
        self._boxes("/world/truth/objects", t, ids, pos, orn, TRUTH_GREY, FillMode.DenseWireframe, labels)
        self._hands("/world/truth/hands", t, row.get("hands") or {}, TRUTH_GREY)
        for oid in ids:
            self._scalar(self._path("plots", "truth", "held", oid), t, float(bool(objects[oid].get("held"))))
        self._relations(("plots", "truth"), t, row.get("relations", []), self._truth_relations_seen)
        for e in row.get("events", []):
            self._text("/log/truth", e["t"], f"true {e['action']} {e['subject']}", "INFO")
        self._done()

    def log_timeline(self, timeline_json: dict) -> None:
        """Log a timeline document (``Timeline.to_json()``) into ``log/timeline``: each fact as a
        "begins" entry at its start and an "ends" entry at its end, each event at its time."""
        self._start(timeline_json.get("t_end") or 0.0)
        for f in timeline_json.get("facts", []):
            name = f"{f['predicate']}({f['subject']}" + (f", {f['object']})" if f.get("object") else ")")
            self._text("/log/timeline", f["start"], f"{name} begins (confidence {f['confidence']:.2f})", "DEBUG")
            if f.get("end") is not None:
                self._text("/log/timeline", f["end"], f"{name} ends", "DEBUG")
        for e in timeline_json.get("events", []):
            self._text("/log/timeline", e["t"], f"{e['action']} {e['subject']} p={e['p']:.2f}", "INFO")



def record_simulation(path: str | os.PathLike, scene: Scene, truth: list[dict], observations: list[dict],
                      options: RecorderOptions | None = None) -> Path:
    """Write a recording of a simulated run: the ``truth`` rows and the ``observations`` frames (dicts
    as in ``truth.jsonl`` / ``observations.jsonl``) over ``scene``. Returns the file's path."""
    from estimator.observations import parse_frame

    with Recorder(path, scene, options=options) as rec:
        for row in truth:
            rec.log_truth(row)
        for obs in observations:
            rec.log_frame(parse_frame(obs, known_ids=scene.object_ids))
    return rec.path
