# SPDX-License-Identifier: Apache-2.0
"""A typed client for a Pliant server (pliant.v1 over gRPC).

Every call raises :class:`pliant.PliantError` (gRPC status code and the server's message) when the
server refuses it; frames come as numpy arrays. The generated messages are in ``pliant.v1.pliant_pb2``
(``pb`` here) for what the wrapper does not cover.
"""
from __future__ import annotations

import logging
import queue
import threading
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Optional, Sequence, Tuple

import grpc
import numpy as np

from .errors import PliantError
from .placement import owner_index
from .v1 import pliant_pb2 as pb
from .v1 import pliant_pb2_grpc as pb_grpc

log = logging.getLogger("pliant")

Vec3Like = Sequence[float]

BUILTIN_MESHES = ("beam1", "beam2", "beam3")

_MODES = {
    "realtime": pb.TICK_MODE_REALTIME,
    "lockstep": pb.TICK_MODE_LOCKSTEP,
    "as-fast-as-possible": pb.TICK_MODE_AS_FAST_AS_POSSIBLE,
}
_METHODS = {
    "xpbd": pb.METHOD_XPBD, "sor": pb.METHOD_SOR, "lambda-sor": pb.METHOD_LAMBDA_SOR,
    "chebyshev": pb.METHOD_CHEBYSHEV, "anderson": pb.METHOD_ANDERSON,
    "anderson-sor": pb.METHOD_ANDERSON_SOR, "extrapolation": pb.METHOD_EXTRAPOLATION,
    "vbd": pb.METHOD_VBD, "newton": pb.METHOD_NEWTON, "auto": pb.METHOD_AUTO,
}
_SWEEPS = {
    "gauss-seidel": pb.SWEEP_GAUSS_SEIDEL, "jacobi": pb.SWEEP_JACOBI,
    "sequential": pb.SWEEP_SEQUENTIAL,
}
_ELASTIC = {"stvk": pb.ELASTIC_MODEL_STVK, "corotated": pb.ELASTIC_MODEL_COROTATED}
_FIELDS = {
    "positions": pb.FRAME_FIELD_POSITIONS, "residuals": pb.FRAME_FIELD_RESIDUALS,
    "solver_stats": pb.FRAME_FIELD_SOLVER_STATS,
}
_SHAPES = {"sphere": pb.TOOL_SHAPE_SPHERE, "capsule": pb.TOOL_SHAPE_CAPSULE}


def _pick(table: dict, name: str, what: str) -> int:
    try:
        return table[name]
    except KeyError:
        raise ValueError(f"{what} must be one of {', '.join(table)}, got {name!r}") from None


def _vec3(v: Vec3Like, what: str) -> pb.Vec3:
    a = [float(x) for x in v]
    if len(a) != 3:
        raise ValueError(f"{what} must have 3 components, got {len(a)}")
    return pb.Vec3(x=a[0], y=a[1], z=a[2])


def _np3(v: pb.Vec3) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=np.float64)


@dataclass
class Frame:
    """One published tick of a scene.

    ``positions`` is an (N, 3) float32 array (all vertices, or the surface vertices in
    ``Topology.surface_vertices`` order when ``surface_only``); empty (0, 3) when not asked for.
    ``skipped_frames`` counts frames this subscriber missed before this one (0 when it kept up).
    """
    tick: int
    sim_time: float
    skipped_frames: int
    positions: np.ndarray
    surface_only: bool
    residuals: np.ndarray
    iterations: int
    residual_final: float
    relative_residual: float
    late_ticks: int
    skipped_ticks: int
    lateness_ms: float
    ticks_per_second: float
    rolled_back: bool
    rollbacks: int
    published_unix_ns: int
    state: int
    message: pb.Frame = field(repr=False)

    @staticmethod
    def from_message(m: pb.Frame) -> "Frame":
        pos = np.frombuffer(np.asarray(m.positions, dtype=np.float32).tobytes(), dtype=np.float32)
        return Frame(
            tick=m.tick, sim_time=m.sim_time, skipped_frames=m.skipped_frames,
            positions=pos.reshape(-1, 3), surface_only=m.surface_only,
            residuals=np.asarray(m.residuals, dtype=np.float64),
            iterations=m.solver.iterations, residual_final=m.solver.residual_final,
            relative_residual=m.solver.relative_residual, late_ticks=m.late_ticks,
            skipped_ticks=m.skipped_ticks, lateness_ms=m.lateness_ms,
            ticks_per_second=m.ticks_per_second, rolled_back=m.rolled_back,
            rollbacks=m.rollbacks, published_unix_ns=m.published_unix_ns, state=m.state,
            message=m)


@dataclass
class Topology:
    """A scene's fixed geometry: rest positions (N, 3), tets (T, 4), surface triangles (F, 3)."""
    rest_positions: np.ndarray
    tets: np.ndarray
    surface_triangles: np.ndarray
    surface_vertices: np.ndarray
    fixed_vertices: np.ndarray

    @property
    def vertex_count(self) -> int:
        return int(self.rest_positions.shape[0])

    @staticmethod
    def from_message(m: pb.Topology) -> "Topology":
        return Topology(
            rest_positions=np.asarray(m.rest_positions, dtype=np.float32).reshape(-1, 3),
            tets=np.asarray(m.tets, dtype=np.int32).reshape(-1, 4),
            surface_triangles=np.asarray(m.surface_triangles, dtype=np.int32).reshape(-1, 3),
            surface_vertices=np.asarray(m.surface_vertices, dtype=np.int32),
            fixed_vertices=np.asarray(m.fixed_vertices, dtype=np.int32))


@dataclass
class ToolFeedback:
    """The force on a haptic tool after one tick."""
    tick: int
    sim_time: float
    pose_seq: int
    force: np.ndarray
    torque: np.ndarray
    contact_count: int
    skipped_ticks: int
    message: pb.ToolFeedback = field(repr=False)


class _Stream:
    """Shared part of the streaming calls: iteration with errors mapped, cancel, context manager."""

    def __init__(self, call: Any, name: str) -> None:
        self._call = call
        self._name = name
        self._cancelled = False

    def cancel(self) -> None:
        """Ends the stream (from any thread); iteration then stops without an error."""
        self._cancelled = True
        self._call.cancel()

    def _next_message(self) -> Any:
        try:
            return next(self._call)
        except StopIteration:
            raise
        except grpc.RpcError as e:
            if self._cancelled and e.code() == grpc.StatusCode.CANCELLED:
                raise StopIteration from None
            raise PliantError.from_rpc_error(e, self._name) from None

    def __enter__(self):
        return self

    def __exit__(self, *exc: Any) -> None:
        self.cancel()


class FrameStream(_Stream):
    """Frames of one scene as :class:`Frame`; iterate, and ``cancel()`` or leave the ``with``."""

    def __iter__(self) -> Iterator[Frame]:
        return self

    def __next__(self) -> Frame:
        return Frame.from_message(self._next_message())

    def messages(self) -> Iterator[pb.Frame]:
        """The raw pliant.v1.Frame messages (no numpy conversion: the cheapest way to keep up
        with a fast scene; convert later with ``Frame.from_message``)."""
        while True:
            try:
                yield self._next_message()
            except StopIteration:
                return


class HapticSession(_Stream):
    """A tool in a scene: ``send()`` poses, iterate :class:`ToolFeedback` (one per tick)."""

    def __init__(self, stub: pb_grpc.InteractionServiceStub, metadata: Any, scene_id: str,
                 shape: str, radius: Optional[float], half_length: Optional[float],
                 static_friction: Optional[float], dynamic_friction: Optional[float]) -> None:
        self._requests: "queue.Queue[Optional[pb.ToolPose]]" = queue.Queue()
        self._seq = 0
        self._first = dict(scene_id=scene_id, shape=_pick(_SHAPES, shape, "shape"))
        for k, v in (("radius", radius), ("half_length", half_length),
                     ("static_friction", static_friction), ("dynamic_friction", dynamic_friction)):
            if v is not None:
                self._first[k] = float(v)
        self._lock = threading.Lock()
        super().__init__(stub.HapticStream(self._poses(), metadata=metadata), "HapticStream")

    def _poses(self) -> Iterator[pb.ToolPose]:
        while True:
            p = self._requests.get()
            if p is None:
                return
            yield p

    def send(self, position: Vec3Like, orientation: Optional[Sequence[float]] = None,
             client_time_ns: int = 0) -> int:
        """Queues a tool pose (position in metres, orientation as w, x, y, z); returns its seq."""
        with self._lock:
            self._seq += 1
            pose = pb.ToolPose(seq=self._seq, client_time_ns=client_time_ns,
                               position=_vec3(position, "position"))
            if self._seq == 1:
                for k, v in self._first.items():
                    setattr(pose, k, v)
            if orientation is not None:
                q = [float(x) for x in orientation]
                if len(q) != 4:
                    raise ValueError(f"orientation must be a quaternion w, x, y, z, got {len(q)} values")
                pose.orientation.CopyFrom(pb.Quaternion(w=q[0], x=q[1], y=q[2], z=q[3]))
            self._requests.put(pose)
            return self._seq

    def close(self) -> None:
        """Ends the poses; the server then ends the stream and removes the tool."""
        self._requests.put(None)

    def __iter__(self) -> Iterator[ToolFeedback]:
        return self

    def __next__(self) -> ToolFeedback:
        m = self._next_message()
        return ToolFeedback(tick=m.tick, sim_time=m.sim_time, pose_seq=m.pose_seq,
                            force=_np3(m.force), torque=_np3(m.torque),
                            contact_count=len(m.contacts), skipped_ticks=m.skipped_ticks, message=m)

    def __exit__(self, *exc: Any) -> None:
        self.close()
        self.cancel()


class Client:
    """One Pliant server.

    ``address`` is HOST:PORT; ``token`` the server's access token (sent as
    ``authorization: Bearer``); ``timeout`` the deadline of each unary call in seconds
    (``step`` gets ``step_timeout``). ``tls=True`` uses TLS with the system roots, or with
    ``tls_ca`` (PEM bytes) for a private CA. ``frame_window_bytes``: frame streams (and
    topology) use a connection of their own whose HTTP/2 receive window stays this small (no
    BDP probing), as the C++ client does, so a reader that pauses finds at most about one stale
    frame before the newest one; 0 uses the main connection with gRPC's default window (64 KiB
    or more of frames then queue up for a paused reader).
    """

    def __init__(self, address: str, token: Optional[str] = None, *, timeout: float = 30.0,
                 step_timeout: float = 600.0, tls: bool = False, tls_ca: Optional[bytes] = None,
                 max_message_mb: int = 64, frame_window_bytes: int = 1) -> None:
        if not address or ":" not in address:
            raise ValueError(f"address must be HOST:PORT, got {address!r}")
        if timeout <= 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout}")
        if frame_window_bytes < 0:
            raise ValueError(f"frame_window_bytes must be >= 0, got {frame_window_bytes}")
        self.address = address
        self.timeout = timeout
        self.step_timeout = step_timeout
        size = max_message_mb * 1024 * 1024
        options = [("grpc.max_receive_message_length", size), ("grpc.max_send_message_length", size)]
        def channel(opts: list) -> grpc.Channel:
            if tls or tls_ca is not None:
                return grpc.secure_channel(
                    address, grpc.ssl_channel_credentials(root_certificates=tls_ca), options=opts)
            return grpc.insecure_channel(address, options=opts)

        self._channel = channel(options)
        self._frame_channel = self._channel
        if frame_window_bytes > 0:
            # Options differ from the main channel's, so gRPC opens a connection of its own.
            self._frame_channel = channel(options + [("grpc.http2.bdp_probe", 0),
                                                     ("grpc.http2.lookahead_bytes", frame_window_bytes)])
        self._metadata = (("authorization", f"Bearer {token}"),) if token else None
        self._scenes = pb_grpc.SceneServiceStub(self._channel)
        self._frames = pb_grpc.FrameServiceStub(self._frame_channel)
        self._snapshots = pb_grpc.SnapshotServiceStub(self._channel)
        self._interaction = pb_grpc.InteractionServiceStub(self._channel)

    # -- plumbing ---------------------------------------------------------------------------

    def close(self) -> None:
        if self._frame_channel is not self._channel:
            self._frame_channel.close()
        self._channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def wait_ready(self, timeout: float = 10.0) -> None:
        """Waits until the channel is connected; PliantError UNAVAILABLE when it is not in time."""
        try:
            grpc.channel_ready_future(self._channel).result(timeout=timeout)
        except grpc.FutureTimeoutError:
            raise PliantError(grpc.StatusCode.UNAVAILABLE,
                              f"no connection to {self.address} within {timeout} s", "connect") from None

    def _call(self, method: Callable, request: Any, name: str, timeout: Optional[float] = None) -> Any:
        try:
            return method(request, timeout=timeout or self.timeout, metadata=self._metadata)
        except grpc.RpcError as e:
            raise PliantError.from_rpc_error(e, name) from None

    # -- scenes -----------------------------------------------------------------------------

    @staticmethod
    def scene_spec(
        mesh: str = "beam1", *, scale: Optional[float] = None,
        young_modulus: Optional[float] = None, poisson_ratio: Optional[float] = None,
        density: Optional[float] = None, elastic_model: Optional[str] = None,
        fixed: Optional[Sequence[int]] = None,
        fixed_boxes: Optional[Sequence[Tuple[Vec3Like, Vec3Like]]] = None,
        fixed_groups: Optional[Sequence[str]] = None,
        fix_x_below: Optional[float] = None, gravity: Optional[Vec3Like] = None,
        rate_hz: Optional[float] = None, dt: Optional[float] = None, mode: Optional[str] = None,
        method: Optional[str] = None, sweep: Optional[str] = None,
        substeps: Optional[int] = None, iterations: Optional[int] = None,
        window: Optional[int] = None, omega: Optional[float] = None,
        time_budget_ms: Optional[float] = None, tolerance: Optional[float] = None,
        threads: Optional[int] = None, start_paused: bool = False,
    ) -> pb.SceneSpec:
        """A SceneSpec from keyword settings; unset ones are the server's defaults.

        ``mesh``: a builtin (beam1, beam2, beam3) or a file / model name on the server's model
        path. ``rate_hz`` or ``dt`` set the tick; ``mode`` is realtime (default), lockstep or
        as-fast-as-possible. ``fixed`` are vertex indices, ``fixed_boxes`` (min, max) corners,
        ``fixed_groups`` physical groups of a Gmsh mesh file (names or tags, resolved by the
        server), ``fix_x_below`` fixes every vertex with x <= that value.
        """
        spec = pb.SceneSpec()
        if not mesh:
            raise ValueError("mesh must name a builtin mesh or a model, got ''")
        if mesh in BUILTIN_MESHES:
            spec.mesh.builtin = mesh
        else:
            spec.mesh.model_path = mesh
        if scale is not None:
            spec.mesh.scale = float(scale)
        for name, value in (("young_modulus", young_modulus), ("poisson_ratio", poisson_ratio),
                            ("density", density)):
            if value is not None:
                setattr(spec.material, name, float(value))
        if elastic_model is not None:
            spec.material.model = _pick(_ELASTIC, elastic_model, "elastic_model")
        if fixed is not None:
            spec.fixed.indices.extend(int(i) for i in fixed)
        for g in fixed_groups or ():
            spec.fixed.groups.append(str(g))
        for lo, hi in fixed_boxes or ():
            b = spec.fixed.boxes.add()
            b.min.CopyFrom(_vec3(lo, "fixed_boxes min"))
            b.max.CopyFrom(_vec3(hi, "fixed_boxes max"))
        if fix_x_below is not None:
            b = spec.fixed.boxes.add()
            b.min.CopyFrom(pb.Vec3(x=-1e9, y=-1e9, z=-1e9))
            b.max.CopyFrom(pb.Vec3(x=float(fix_x_below), y=1e9, z=1e9))
        if gravity is not None:
            spec.gravity.CopyFrom(_vec3(gravity, "gravity"))
        if rate_hz is not None and dt is not None:
            raise ValueError("give rate_hz or dt, not both")
        if rate_hz is not None:
            if rate_hz <= 0:
                raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
            spec.tick.dt = 1.0 / rate_hz
        if dt is not None:
            spec.tick.dt = float(dt)
        if mode is not None:
            spec.tick.mode = _pick(_MODES, mode, "mode")
        if method is not None:
            spec.solver.method = _pick(_METHODS, method, "method")
        if sweep is not None:
            spec.solver.sweep = _pick(_SWEEPS, sweep, "sweep")
        for name, value in (("substeps", substeps), ("iterations", iterations), ("threads", threads),
                            ("window", window)):
            if value is not None:
                setattr(spec.solver, name, int(value))
        for name, value in (("time_budget_ms", time_budget_ms), ("tolerance", tolerance),
                            ("omega", omega)):
            if value is not None:
                setattr(spec.solver, name, float(value))
        spec.start_paused = start_paused
        return spec

    def create_scene(self, scene_id: str = "", mesh: str = "beam1", *,
                     spec: Optional[pb.SceneSpec] = None, **settings: Any) -> pb.Scene:
        """Creates a scene (``scene_id`` empty: the server picks one) and returns it.

        Settings are :meth:`scene_spec`'s keywords, or a ready ``spec``.
        """
        if spec is None:
            spec = self.scene_spec(mesh, **settings)
        elif settings:
            raise ValueError("give either spec or keyword settings, not both")
        return self._call(self._scenes.CreateScene,
                          pb.CreateSceneRequest(scene_id=scene_id, spec=spec), "CreateScene")

    def list_scenes(self) -> list:
        """Every scene of this server (pliant.v1.Scene), sorted by id."""
        return list(self._call(self._scenes.ListScenes, pb.ListScenesRequest(), "ListScenes").scenes)

    def get_scene(self, scene_id: str) -> pb.Scene:
        return self._call(self._scenes.GetScene, pb.GetSceneRequest(scene_id=scene_id), "GetScene")

    def delete_scene(self, scene_id: str) -> None:
        self._call(self._scenes.DeleteScene, pb.DeleteSceneRequest(scene_id=scene_id), "DeleteScene")

    def reset_scene(self, scene_id: str) -> pb.Scene:
        return self._call(self._scenes.ResetScene, pb.ResetSceneRequest(scene_id=scene_id), "ResetScene")

    def pause_scene(self, scene_id: str) -> pb.Scene:
        return self._call(self._scenes.PauseScene, pb.PauseSceneRequest(scene_id=scene_id), "PauseScene")

    def resume_scene(self, scene_id: str) -> pb.Scene:
        return self._call(self._scenes.ResumeScene, pb.ResumeSceneRequest(scene_id=scene_id), "ResumeScene")

    def update_scene(self, request: pb.UpdateSceneRequest) -> pb.Scene:
        return self._call(self._scenes.UpdateScene, request, "UpdateScene")

    def step(self, scene_id: str, ticks: int = 1) -> pb.StepResponse:
        """Advances a lockstep or paused scene ``ticks`` ticks and returns once they are done."""
        if ticks < 1:
            raise ValueError(f"ticks must be >= 1, got {ticks}")
        return self._call(self._scenes.Step, pb.StepRequest(scene_id=scene_id, ticks=ticks), "Step",
                          timeout=self.step_timeout)

    def apply_force(self, scene_id: str, vertices: Sequence[int], force: Vec3Like,
                    ticks: int = 1) -> int:
        """Pushes ``vertices`` with ``force`` (N each) for ``ticks`` ticks; returns the first tick."""
        r = self._call(self._scenes.ApplyForce,
                       pb.ApplyForceRequest(scene_id=scene_id, vertices=[int(v) for v in vertices],
                                            force=_vec3(force, "force"), ticks=ticks), "ApplyForce")
        return r.first_tick

    # -- frames -----------------------------------------------------------------------------

    def topology(self, scene_id: str) -> Topology:
        return Topology.from_message(
            self._call(self._frames.GetTopology, pb.GetTopologyRequest(scene_id=scene_id), "GetTopology"))

    def frames(self, scene_id: str, *, fields: Optional[Sequence[str]] = None,
               surface_only: bool = False, every_nth_tick: int = 1,
               max_rate_hz: float = 0.0) -> FrameStream:
        """The scene's frames as they are published (``fields``: positions, residuals,
        solver_stats; default all). Iterate the result; it has no deadline."""
        req = pb.StreamFramesRequest(scene_id=scene_id, surface_only=surface_only,
                                     every_nth_tick=every_nth_tick, max_rate_hz=max_rate_hz)
        for f in fields or ():
            req.fields.append(_pick(_FIELDS, f, "fields"))
        return FrameStream(self._frames.StreamFrames(req, metadata=self._metadata), "StreamFrames")

    # -- snapshots --------------------------------------------------------------------------

    def save_snapshot(self, scene_id: str, name: str = "") -> pb.SaveSnapshotResponse:
        return self._call(self._snapshots.SaveSnapshot,
                          pb.SaveSnapshotRequest(scene_id=scene_id, name=name), "SaveSnapshot")

    def restore_snapshot(self, snapshot: pb.Snapshot, scene_id: str = "",
                         replace: bool = False) -> pb.Scene:
        return self._call(self._snapshots.RestoreSnapshot,
                          pb.RestoreSnapshotRequest(snapshot=snapshot, scene_id=scene_id,
                                                    replace=replace), "RestoreSnapshot")

    # -- interaction ------------------------------------------------------------------------

    def grab(self, scene_id: str, vertex: Optional[int] = None, *,
             tet: Optional[int] = None, barycentric: Optional[Sequence[float]] = None,
             target: Optional[Vec3Like] = None, compliance: Optional[float] = None) -> int:
        """Attaches a vertex (or a point in a tet) to ``target`` (default: where it is); returns the grab id."""
        req = pb.GrabRequest(scene_id=scene_id)
        if (vertex is None) == (tet is None):
            raise ValueError("grab needs exactly one of vertex or tet (with barycentric)")
        if vertex is not None:
            req.vertex = int(vertex)
        else:
            req.tet_point.tet = int(tet)
            req.tet_point.barycentric.extend(float(b) for b in (barycentric or ()))
        if target is not None:
            req.target.CopyFrom(_vec3(target, "target"))
        if compliance is not None:
            req.compliance = float(compliance)
        return self._call(self._interaction.Grab, req, "Grab").grab_id

    def move_grab(self, scene_id: str, grab_id: int, target: Vec3Like) -> np.ndarray:
        """Moves a grab's target; returns the force (N) the grab put on the body in the last tick."""
        r = self._call(self._interaction.MoveGrab,
                       pb.MoveGrabRequest(scene_id=scene_id, grab_id=grab_id,
                                          target=_vec3(target, "target")), "MoveGrab")
        return _np3(r.force)

    def release(self, scene_id: str, grab_id: int) -> None:
        self._call(self._interaction.Release, pb.ReleaseRequest(scene_id=scene_id, grab_id=grab_id),
                   "Release")

    def haptic(self, scene_id: str, shape: str = "sphere", *, radius: Optional[float] = None,
               half_length: Optional[float] = None, static_friction: Optional[float] = None,
               dynamic_friction: Optional[float] = None) -> HapticSession:
        """Opens the haptic stream with a tool of ``shape`` (sphere or capsule). The tool
        enters the scene with the first pose sent."""
        return HapticSession(self._interaction, self._metadata, scene_id, shape, radius,
                             half_length, static_friction, dynamic_friction)


class ShardedClient:
    """Several servers, each scene on the one :func:`pliant.placement.owner_index` names.

    ``servers`` is the ordered list of addresses (a StatefulSet's pods in ordinal order); every
    client must use the same order. Calls about one scene go to its owner; ``list_scenes``
    asks every server.
    """

    def __init__(self, servers: Sequence[str], token: Optional[str] = None, **options: Any) -> None:
        if not servers:
            raise ValueError("servers must list at least one address")
        self.servers = list(servers)
        self.clients = [Client(a, token, **options) for a in self.servers]

    def owner_index(self, scene_id: str) -> int:
        return owner_index(scene_id, len(self.servers))

    def client_for(self, scene_id: str) -> Client:
        """The client of the server that holds (or will hold) ``scene_id``."""
        return self.clients[self.owner_index(scene_id)]

    def create_scene(self, scene_id: str, mesh: str = "beam1", **settings: Any) -> pb.Scene:
        if not scene_id:
            raise ValueError("scene_id must be given: placement needs it")
        return self.client_for(scene_id).create_scene(scene_id, mesh, **settings)

    def get_scene(self, scene_id: str) -> pb.Scene:
        return self.client_for(scene_id).get_scene(scene_id)

    def delete_scene(self, scene_id: str) -> None:
        self.client_for(scene_id).delete_scene(scene_id)

    def step(self, scene_id: str, ticks: int = 1) -> pb.StepResponse:
        return self.client_for(scene_id).step(scene_id, ticks)

    def frames(self, scene_id: str, **options: Any) -> FrameStream:
        return self.client_for(scene_id).frames(scene_id, **options)

    def topology(self, scene_id: str) -> Topology:
        return self.client_for(scene_id).topology(scene_id)

    def list_scenes(self) -> list:
        """(server index, Scene) for every scene on every server."""
        return [(k, s) for k, c in enumerate(self.clients) for s in c.list_scenes()]

    def close(self) -> None:
        for c in self.clients:
            c.close()

    def __enter__(self) -> "ShardedClient":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
