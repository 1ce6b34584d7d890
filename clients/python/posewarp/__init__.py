"""posewarp: re-pose segmented CT/MRI studies on a posewarp-server, with numpy arrays in and out.

    import posewarp
    with posewarp.Client("127.0.0.1:50051") as client:
        labels = client.upload("seg.nii.gz", kind="labels")           # or client.upload((array, affine))
        ct = client.upload("ct.nii.gz", kind="intensity")
        rig = client.build_rig(labels, ct, preset="totalsegmentator", progress=print)
        posed = client.pose(rig, joints={"hip_left": {"flexion": 30}}, method="cor")
        posed.labels, posed.ct, posed.affine, posed.report            # (x, y, z) arrays, RAS affine, dict
        posed.to_nibabel("labels").to_filename("posed_labels.nii.gz")

Every call the server refuses raises a PosewarpError subclass (InvalidArgumentError, NotFoundError, ...) whose
.code is the gRPC status code and whose message says what to fix. Runtime: grpcio, protobuf and numpy (Debian's
python3-grpcio, python3-protobuf, python3-numpy); nibabel for arrays in and to_nibabel().
"""
from __future__ import annotations

import hashlib
import json
import os
import pkgutil
import re
import time
from typing import Any, Callable, Dict, Iterator, List, Mapping, NamedTuple, Optional, Sequence, Tuple, Union

# The stubs (posewarp.v1) sit in this package once installed; in a build tree they are generated apart
# (build/clients/python/generated/posewarp/v1), found on the path after this folder.
__path__ = pkgutil.extend_path(__path__, __name__)

import grpc  # noqa: E402
import numpy as np  # noqa: E402

from posewarp.v1 import posewarp_pb2 as pb  # noqa: E402
from posewarp.v1 import posewarp_pb2_grpc as rpc  # noqa: E402

__version__ = "0.1.0"
__all__ = ["Client", "PoseResult", "MatchResult", "Surface", "make_pose", "PosewarpError", "InvalidArgumentError", "NotFoundError",
           "FailedPreconditionError", "ResourceExhaustedError", "UnavailableError", "DeadlineExceededError",
           "PermissionDeniedError", "UnauthenticatedError", "DataLossError"]

_CHUNK = 1 << 20
_FORMATS = {".nii.gz": pb.FILE_FORMAT_NIFTI_GZ, ".nii": pb.FILE_FORMAT_NIFTI, ".nrrd": pb.FILE_FORMAT_NRRD,
            ".mha": pb.FILE_FORMAT_MHA}
_METHODS = {"cor": pb.METHOD_COR, "dqs": pb.METHOD_DQS, "lbs": pb.METHOD_LBS, "fem": pb.METHOD_FEM}
_DTYPES = {"uint8": np.uint8, "int8": np.int8, "uint16": np.uint16, "int16": np.int16, "uint32": np.uint32,
           "int32": np.int32, "float32": np.float32, "float64": np.float64}
_ANGLES = ("flexion", "abduction", "rotation")

PathLike = Union[str, "os.PathLike[str]"]
Volume = Tuple[np.ndarray, np.ndarray]  # (array, RAS affine)


class PosewarpError(RuntimeError):
    """A call the server refused, or an answer this client could not use: .code is the gRPC status code
    (grpc.StatusCode), .message says what to fix. Each code a caller is likely to handle has its own subclass."""

    def __init__(self, code: grpc.StatusCode, message: str):
        super().__init__(f"{code.name}: {message}")
        self.code = code
        self.message = message


class InvalidArgumentError(PosewarpError):
    """A bad request or input (INVALID_ARGUMENT): a misspelt joint, an angle out of range, a volume that is no
    segmentation. The message names what to change."""


class NotFoundError(PosewarpError):
    """No such rig, volume or operation on this server (NOT_FOUND)."""


class FailedPreconditionError(PosewarpError):
    """The request does not fit the server's state (FAILED_PRECONDITION), e.g. a rig that must be rebuilt."""


class ResourceExhaustedError(PosewarpError):
    """Over a limit of the server (RESOURCE_EXHAUSTED): its memory, its queue, an output too large. Try later or ask
    for less."""


class UnavailableError(PosewarpError):
    """The server cannot be reached or is shutting down (UNAVAILABLE), after the client's retries."""


class DeadlineExceededError(PosewarpError):
    """The call took longer than the client's timeout_s (DEADLINE_EXCEEDED)."""


class PermissionDeniedError(PosewarpError):
    """The token is not allowed this call (PERMISSION_DENIED)."""


class UnauthenticatedError(PosewarpError):
    """No token, or not the server's (UNAUTHENTICATED)."""


class DataLossError(PosewarpError):
    """The server's answer was damaged or ended early (DATA_LOSS); posing again usually succeeds."""


_ERRORS = {grpc.StatusCode.INVALID_ARGUMENT: InvalidArgumentError, grpc.StatusCode.NOT_FOUND: NotFoundError,
           grpc.StatusCode.FAILED_PRECONDITION: FailedPreconditionError,
           grpc.StatusCode.RESOURCE_EXHAUSTED: ResourceExhaustedError, grpc.StatusCode.UNAVAILABLE: UnavailableError,
           grpc.StatusCode.DEADLINE_EXCEEDED: DeadlineExceededError,
           grpc.StatusCode.PERMISSION_DENIED: PermissionDeniedError,
           grpc.StatusCode.UNAUTHENTICATED: UnauthenticatedError, grpc.StatusCode.DATA_LOSS: DataLossError}


def _error(code: grpc.StatusCode, message: str) -> PosewarpError:
    return _ERRORS.get(code, PosewarpError)(code, message)


class Surface(NamedTuple):
    """A posed surface: vertices (n, 3) float64 in LPS mm, faces (m, 3) int32 triangles into them."""
    vertices: np.ndarray
    faces: np.ndarray


class PoseResult:
    """A posed study.

    labels, ct: (x, y, z) numpy arrays on the output grid (None when not asked for), in the study's own types by
    default (uint8 labels, int16 CT). affine: the grid's 4x4 RAS affine, as nibabel uses it. surfaces: {name:
    Surface} in LPS mm. report: the quality report as a dict (the CLI's JSON). With fields=True, inverse_field (output
    grid) and forward_field (study grid) as (x, y, z, 3) float32 arrays of LPS mm displacements."""

    def __init__(self, labels: Optional[np.ndarray], ct: Optional[np.ndarray], affine: np.ndarray,
                 surfaces: Dict[str, Surface], report: Dict[str, Any]):
        self.labels, self.ct, self.affine, self.surfaces, self.report = labels, ct, affine, surfaces, report
        self.inverse_field: Optional[np.ndarray] = None
        self.forward_field: Optional[np.ndarray] = None

    def to_nibabel(self, which: str = "labels"):
        """The posed labels ("labels") or CT ("ct") as a nibabel.Nifti1Image with its affine, ready to_filename()."""
        import nibabel  # only needed here
        if which not in ("labels", "ct"):
            raise ValueError("to_nibabel takes 'labels' or 'ct'")
        array = getattr(self, which)
        if array is None:
            raise ValueError(f"this pose was asked without {which}; pose with {which}=True")
        image = nibabel.Nifti1Image(array, self.affine)
        image.header.set_xyzt_units("mm")
        return image


class MatchResult(NamedTuple):
    """A posture matched (Client.match).

    pose: the pose found as the CLI's pose JSON (a dict; pose() takes it). segments: per bone a dict with segment,
    joint ("" for the root), matched, skipped (why not), volume_ml, angles ((flexion, abduction, rotation) degrees),
    mean_distance_mm and max_distance_mm (its surface to the target bone's), dice (with the target bone),
    iterations, beyond_range (past the range measured on the rig's study) and held_at_range (held back by the joint's
    anatomical range). report: the match report (posewarp.match) as a dict. unnamed_labels: the rig's labels the
    target's map does not name. target_grid: the target's grid; pose(..., grid=result.target_grid) poses onto it, to
    compare voxel by voxel. A standard posture has only pose."""
    pose: Dict[str, Any]
    segments: List[Dict[str, Any]]
    report: Dict[str, Any]
    unnamed_labels: List[str]
    seconds: float
    target_grid: Any


def _joint_rotation(joint: str, angles: Any) -> Tuple[str, Any]:
    """A joint's rotation as ("angles", (flexion, abduction, rotation)), ("quaternion", [w, x, y, z]) or
    ("axis_angle", {"axis": [x, y, z], "degrees": d})."""
    if isinstance(angles, Mapping) and "quaternion" in angles:
        return "quaternion", [float(v) for v in angles["quaternion"]]
    if isinstance(angles, Mapping) and "axis_angle" in angles:
        axis_angle = angles["axis_angle"]
        return "axis_angle", {"axis": [float(v) for v in axis_angle["axis"]], "degrees": float(axis_angle["degrees"])}
    if isinstance(angles, Mapping):
        given = angles.get("angles_deg", angles)
        unknown = set(given) - set(_ANGLES)
        if unknown:
            raise ValueError(f"joint {joint!r}: angles are {', '.join(_ANGLES)} (degrees), not {sorted(unknown)}")
        return "angles", tuple(float(given.get(name, 0.0)) for name in _ANGLES)
    values = tuple(float(v) for v in angles)
    if len(values) != 3:
        raise ValueError(f"joint {joint!r}: give (flexion, abduction, rotation) in degrees")
    return "angles", values


def make_pose(joints: Optional[Mapping[str, Any]] = None, root: Optional[Mapping[str, Any]] = None,
              name: str = "") -> Dict[str, Any]:
    """A pose as a pose file holds it (posewarp.pose version 1, the JSON the CLI reads), e.g. to save with json.dump.

    joints: {joint: angles}, where angles are anatomical degrees, either a mapping with any of "flexion",
    "abduction" and "rotation", or a sequence (flexion, abduction, rotation); a mapping with "quaternion" [w, x, y,
    z] or "axis_angle" {"axis": [x, y, z], "degrees": d} is a rotation in the joint's frame. root:
    {"translation_mm": [x, y, z], "rotation": {"quaternion": [...]} or {"axis_angle": {...}}} in LPS. Joints not
    named stay at rest; the server checks the names against the rig (Client.joints() lists them) and answers a
    misspelt one with InvalidArgumentError naming the rig's joints."""
    pose: Dict[str, Any] = {"format": "posewarp.pose", "version": 1}
    if name:
        pose["name"] = name
    if root is not None:
        pose["root"] = dict(root)
    converted: Dict[str, Any] = {}
    for joint, angles in (joints or {}).items():
        form, value = _joint_rotation(joint, angles)
        converted[joint] = {"angles_deg": dict(zip(_ANGLES, value))} if form == "angles" else {form: value}
    pose["joints"] = converted
    return pose


def _put_rotation(rotation: Mapping[str, Any], out) -> None:
    if "quaternion" in rotation:
        out.quaternion.w, out.quaternion.x, out.quaternion.y, out.quaternion.z = (float(v) for v in
                                                                                  rotation["quaternion"])
    elif "axis_angle" in rotation:
        out.axis_angle.axis.extend(float(v) for v in rotation["axis_angle"]["axis"])
        out.axis_angle.degrees = float(rotation["axis_angle"]["degrees"])
    else:
        raise ValueError("a rotation is {'quaternion': [w, x, y, z]} or {'axis_angle': {'axis': [...], 'degrees': d}}")


def _typed_pose(joints: Optional[Mapping[str, Any]], root: Optional[Mapping[str, Any]], name: str = ""):
    """The pose as the proto's typed Pose (what the server checks and poses exactly as the same pose in JSON)."""
    message = pb.Pose(name=name)
    if root is not None:
        message.root.SetInParent()
        if "translation_mm" in root:
            message.root.translation_mm.extend(float(v) for v in root["translation_mm"])
        if root.get("rotation"):
            _put_rotation(root["rotation"], message.root.rotation)
        unknown = set(root) - {"translation_mm", "rotation"}
        if unknown:
            raise ValueError(f"root takes translation_mm and rotation, not {sorted(unknown)}")
    for joint, angles in (joints or {}).items():
        typed = message.joints.add(joint=joint)
        form, value = _joint_rotation(joint, angles)
        if form == "angles":
            typed.angles.SetInParent()
            typed.angles.flexion_deg, typed.angles.abduction_deg, typed.angles.rotation_deg = value
        else:
            _put_rotation({form: value}, typed)
    return message


def _affine(grid) -> np.ndarray:
    """The NIfTI (RAS) affine of a grid in LPS millimetres."""
    direction = np.array(grid.direction, dtype=float).reshape(3, 3)
    lps = np.eye(4)
    lps[:3, :3] = direction @ np.diag(np.array(grid.spacing, dtype=float))
    lps[:3, 3] = np.array(grid.origin, dtype=float)
    return np.diag([-1.0, -1.0, 1.0, 1.0]) @ lps


def _volume(data: bytes, grid, dtype) -> np.ndarray:
    """Voxels sent x fastest as an (x, y, z) array."""
    size = tuple(grid.size)
    return np.frombuffer(data, dtype=dtype).reshape(size[2], size[1], size[0]).transpose(2, 1, 0)


def _runs(data: bytes, dtype, room: Optional[int] = None) -> bytes:
    """The samples of a chunk of runs: (value as dtype, count as uint32) pairs, little-endian, packed. A chunk no
    well-behaved server sends (a torn pair, a run of none, more samples than `room` left of the size its header gave)
    is DATA_LOSS, as the C++ clients answer it: nothing is allocated for it."""
    pair = np.dtype([("value", np.dtype(dtype).newbyteorder("<")), ("count", "<u4")])
    if len(data) % pair.itemsize:
        raise DataLossError(grpc.StatusCode.DATA_LOSS, f"the server's labels end inside a run ({len(data)} bytes "
                            f"of {pair.itemsize}-byte runs); pose again")
    pairs = np.frombuffer(data, dtype=pair)
    if (pairs["count"] == 0).any():
        raise DataLossError(grpc.StatusCode.DATA_LOSS, "the server's labels hold a run of no samples; pose again")
    total = int(pairs["count"].sum(dtype=np.uint64))
    if room is not None and total > room:
        raise DataLossError(grpc.StatusCode.DATA_LOSS, f"the server's labels run {total} samples past the "
                            f"{room} its header left room for; pose again")
    return np.repeat(pairs["value"], pairs["count"]).tobytes()


class Client:
    """A connection to one posewarp-server (or a proxy in front of replicas). Use it as a context manager, or
    close() it."""

    def __init__(self, address: str, timeout_s: float = 600.0, token: Optional[str] = None,
                 tls_ca: Optional[PathLike] = None, retries: int = 3):
        """address: HOST:PORT. token: the server's bearer token (or None). tls_ca: path of the CA certificate (PEM)
        of a TLS server. timeout_s: the deadline of each call. retries: calls answered UNAVAILABLE (a server
        restarting) are tried again this many times, 0.5 s apart and doubling (gRPC's own retry policy, which stops
        at a stream's first answer; a pose whose stream a proxy cut in mid-answer, its replica gone, is posed again
        by pose() itself)."""
        policy = {"methodConfig": [{"name": [{"service": "posewarp.v1.Posewarp"}], "retryPolicy": {
            "maxAttempts": retries + 1, "initialBackoff": "0.5s", "maxBackoff": "8s", "backoffMultiplier": 2,
            "retryableStatusCodes": ["UNAVAILABLE"]}}]} if retries > 0 else {}
        options = [("grpc.max_receive_message_length", 64 << 20), ("grpc.enable_retries", 1 if retries > 0 else 0),
                   ("grpc.service_config", json.dumps(policy)),
                   ("grpc.initial_reconnect_backoff_ms", 250), ("grpc.max_reconnect_backoff_ms", 2000)]
        if tls_ca:
            with open(tls_ca, "rb") as f:
                credentials = grpc.ssl_channel_credentials(root_certificates=f.read())
            self._channel = grpc.secure_channel(address, credentials, options=options)
        else:
            self._channel = grpc.insecure_channel(address, options=options)
        self._stub = rpc.PosewarpStub(self._channel)
        self._timeout = timeout_s
        self._retries = max(0, retries)
        self._metadata: Tuple[Tuple[str, str], ...] = (("authorization", "Bearer " + token.strip()),) if token else ()

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _call(self, method, request):
        try:
            return method(request, timeout=self._timeout, metadata=self._metadata)
        except grpc.RpcError as error:
            raise _error(error.code(), error.details()) from None

    def upload(self, source: Union[PathLike, Volume, None] = None, kind: str = "labels", *,
               array: Optional[np.ndarray] = None, affine: Optional[np.ndarray] = None, path=None) -> str:
        """Uploads a volume and returns its id (the same bytes are stored once).

        source: a file (.nii.gz, .nii, .nrrd, .mha), or (array, affine): an (x, y, z) numpy array with its 4x4 RAS
        affine, sent as NIfTI (nibabel). kind: "labels" (a segmentation) or "intensity" (the CT or MR)."""
        if path is not None:  # the keyword of posewarp_client
            source = path
        if array is None and isinstance(source, tuple):
            array, affine = source
        if kind not in ("labels", "intensity"):
            raise ValueError("kind is 'labels' or 'intensity'")
        if array is not None:
            import nibabel  # only needed for arrays
            image = nibabel.Nifti1Image(np.asarray(array), affine if affine is not None else np.eye(4))
            data, fmt = image.to_bytes(), pb.FILE_FORMAT_NIFTI
        else:
            if source is None:
                raise ValueError("upload takes a file path or an (array, affine) pair")
            fmt = next((f for ext, f in _FORMATS.items() if str(source).endswith(ext)), None)
            if fmt is None:
                raise ValueError(f"{source}: the server takes .nii.gz, .nii, .nrrd or .mha files")
            with open(source, "rb") as f:
                data = f.read()
        header = pb.UploadVolumeHeader(
            kind=pb.VOLUME_KIND_LABELS if kind == "labels" else pb.VOLUME_KIND_INTENSITY, format=fmt,
            size_bytes=len(data), sha256=hashlib.sha256(data).hexdigest())

        def parts() -> Iterator[Any]:
            yield pb.UploadVolumeRequest(header=header)
            for offset in range(0, len(data), _CHUNK):
                yield pb.UploadVolumeRequest(chunk=data[offset:offset + _CHUNK])

        return self._call(self._stub.UploadVolume, parts()).id

    def build_rig(self, labels_id: str, ct_id: str = "", preset: str = "", label_map: Any = None,
                  rig_spec: Any = None, name: str = "",
                  progress: Optional[Callable[[str, float], None]] = None) -> str:
        """Builds (or finds) the rig of uploaded volumes and returns its id. preset: a label map the server knows
        ("totalsegmentator"), or label_map: the label map as a dict or JSON text. progress(stage, fraction) is called
        as the build runs. Raises a PosewarpError when the build fails."""
        request = pb.BuildRigRequest(labels_volume_id=labels_id, ct_volume_id=ct_id or "", preset=preset, name=name,
                                     label_map_json=_json_text(label_map), rig_spec_json=_json_text(rig_spec))
        operation = self._call(self._stub.BuildRig, request)
        try:
            for state in self._stub.WatchOperation(pb.GetOperationRequest(operation_id=operation.id),
                                                   timeout=self._timeout, metadata=self._metadata):
                operation = state
                if progress and state.stage:
                    progress(state.stage, state.stage_fraction)
        except grpc.RpcError as error:
            raise _error(error.code(), error.details()) from None
        if operation.state != pb.Operation.SUCCEEDED:
            code = grpc.StatusCode.UNKNOWN if not operation.error_code else _code(operation.error_code)
            raise _error(code, operation.error_message or "the build did not succeed")
        return operation.rig_id

    def rigs(self) -> List[Tuple[str, str, int, str]]:
        """[(id, name, size_bytes, created)] of the rigs the server holds."""
        found: List[Tuple[str, str, int, str]] = []
        token = ""
        while True:
            page = self._call(self._stub.ListRigs, pb.ListRigsRequest(page_size=1000, page_token=token))
            found += [(r.id, r.name, r.size_bytes, r.created) for r in page.rigs]
            token = page.next_page_token
            if not token:
                return found

    def joints(self, rig_id: str) -> List[Dict[str, Any]]:
        """The rig's joints, to build a pose from: each a dict with name, parent and child (segments), kind ("ball",
        "hinge" or "plane"), centre_mm, method and placed_because (how the centre was found, and why there, in a
        sentence), the flexion, abduction and rotation axes (unit vectors, LPS) and the ranges measured at rig build
        ({motion: (negative_deg, positive_deg)}: how far it turns before its bones meet)."""
        rig = self._call(self._stub.GetRig, pb.GetRigRequest(rig_id=rig_id))
        return [{"name": j.name, "parent": j.parent, "child": j.child, "kind": j.kind,
                 "centre_mm": list(j.centre_mm), "method": j.method, "placed_because": j.placed_because,
                 "flexion_axis": list(j.flexion_axis),
                 "abduction_axis": list(j.abduction_axis), "rotation_axis": list(j.rotation_axis),
                 "ranges": {r.motion: (r.negative_deg, r.positive_deg) for r in j.ranges}} for j in rig.joints]

    def match(self, rig_id: str, target: Union[str, PathLike, Volume, None] = None, *, standard: str = "",
              preset: str = "", label_map: Any = None, free_hinges: bool = False,
              beyond_range: bool = False) -> MatchResult:
        """The pose that brings the rig's bones onto the same bones in another scan's labels, or a standard posture.

        target: the other scan's labels: an uploaded volume's id, a label file, or (array, affine) (uploaded first);
        or standard: "limbs-straight" (or "supine-arms-down"), "arms-up". The target's labels are found by name:
        preset (a label map the server knows) or label_map (a dict or JSON text) names them; neither: the rig's own
        map (the same values). free_hinges lets knees, elbows and ankles turn every way; beyond_range lets the limbs'
        joints turn past anatomy's range of motion. Raises a PosewarpError as every call does (InvalidArgumentError
        when the target lacks the root's bone, names nothing, or the posture is unknown)."""
        if (target is None) == (not standard):
            raise ValueError("match takes a target (labels of another scan) or standard=NAME, one of the two")
        target_id = ""
        if target is not None:
            if isinstance(target, str) and re.fullmatch(r"[0-9a-f]{64}", target):
                target_id = target
            else:
                target_id = self.upload(target, kind="labels")
        request = pb.MatchPostureRequest(rig_id=rig_id, target_labels_volume_id=target_id, standard=standard,
                                         preset=preset, label_map_json=_json_text(label_map),
                                         free_hinges=free_hinges, beyond_range=beyond_range)
        answer = self._call(self._stub.MatchPosture, request)
        segments = [{"segment": s.segment, "joint": s.joint, "matched": s.matched, "skipped": s.skipped,
                     "volume_ml": s.volume_ml,
                     "angles": (s.angles.flexion_deg, s.angles.abduction_deg, s.angles.rotation_deg),
                     "mean_distance_mm": s.mean_distance_mm, "max_distance_mm": s.max_distance_mm, "dice": s.dice,
                     "iterations": s.iterations, "beyond_range": s.beyond_range, "held_at_range": s.held_at_range}
                    for s in answer.segments]
        return MatchResult(json.loads(answer.pose_json), segments,
                           json.loads(answer.report_json) if answer.report_json else {},
                           list(answer.unnamed_labels), answer.seconds,
                           answer.target_grid if answer.HasField("target_grid") else None)

    def pose(self, rig_id: str, pose: Union[Mapping[str, Any], PathLike, None] = None, method: str = "cor",
             grid: Any = "input", labels: bool = True, ct: bool = True, surfaces: bool = False,
             samples: str = "stored", fields: bool = False,
             meshes: Optional[Mapping[str, Tuple[Sequence, Sequence]]] = None, fem_iterations: int = 0,
             fem_volume_weight: float = 0.0, label_runs: bool = True, *,
             joints: Optional[Mapping[str, Any]] = None, root: Optional[Mapping[str, Any]] = None,
             fem_contact: bool = False, fem_refine: Optional[int] = None) -> PoseResult:
        """Poses a rig and returns the PoseResult.

        The pose: joints={"knee_left": {"flexion": 90}, "hip_right": (30, 10, 0)} (anatomical degrees: flexion,
        abduction, rotation; joints() lists the rig's) and root={"translation_mm": [...], "rotation": {...}}, as
        make_pose() takes them, sent as the proto's typed Pose; or `pose`, the CLI's pose JSON as a dict, or the path
        of a pose file.

        method: "cor" (centres of rotation, the default), "dqs", "lbs" or "fem" (CoR refined by the soft tissue's
        volume-preserving steady state: slower, folds less tissue at bent joints). With "fem", fem_iterations (1 to
        10000, default 20: more converges further and takes longer) and fem_volume_weight (how much more keeping
        volume counts than keeping shape, default 100) tune its solve; 0 keeps the server's default; fem_contact=True
        pushes the skin that bending drives into the tissue facing it back out (slower by about half); fem_refine (0 to
        1000; None, the default, keeps the server's 3) is how many Newton iterations of the nonlinear material with a
        volume per compressed vertex star and no new folds follow the solve, which give back the volume a bent hip
        loses, at 0.1-0.2 s an iteration there (0: none; no contact term: skin fem_contact kept out may pass
        back in). grid: "input"
        (the study's grid), "grow" (grown to hold the posed body), or another scan's grid (a match's target_grid).

        samples: "stored" gives each volume in the study's own type (the CT rounded as a file stores it, the fewest
        bytes); "computed" gives int32 labels and float32 CT as computed. fields: also the inverse (output grid) and
        forward (study grid) displacement fields, (x, y, z, 3) float32 arrays in LPS mm. meshes: {name: (vertices,
        triangles)} of your own in rest space (LPS mm), posed and returned among the surfaces. label_runs: the labels
        travel as runs of equal values (a fraction of their samples' bytes) and come back as the same array."""
        typed = None
        if joints is not None or root is not None:
            if pose is not None:
                raise ValueError("give the pose either as joints=/root= or as `pose`, not both")
            typed = _typed_pose(joints, root)
        elif pose is None:
            raise ValueError("pose takes joints={...} (and root=), a pose dict or a pose file")
        elif isinstance(pose, (str, os.PathLike)) and os.path.exists(pose):
            with open(pose) as f:
                pose = json.load(f)
        if method not in _METHODS:
            raise ValueError(f"method is one of {', '.join(_METHODS)}")
        if samples not in ("stored", "computed"):
            raise ValueError("samples is 'stored' or 'computed'")
        given = grid if isinstance(grid, pb.Grid) else None
        if given is None and grid not in ("input", "grow"):
            raise ValueError("grid is 'input', 'grow' or a grid (a match's target_grid)")
        request = pb.PoseRequest(rig_id=rig_id, method=_METHODS[method],
                                 grid=pb.GRID_POLICY_GIVEN if given is not None else
                                 pb.GRID_POLICY_GROW if grid == "grow" else pb.GRID_POLICY_INPUT,
                                 given_grid=given,
                                 want_labels=labels, want_ct=ct, want_surfaces=surfaces or bool(meshes),
                                 samples=pb.SAMPLE_TYPE_STORED if samples == "stored" else pb.SAMPLE_TYPE_COMPUTED,
                                 want_fields=fields,
                                 fem=pb.FemOptions(max_iterations=fem_iterations, volume_weight=fem_volume_weight,
                                                   contact=fem_contact,
                                                   **({} if fem_refine is None else
                                                      {"refine_iterations": fem_refine})),
                                 label_encoding=pb.LABEL_ENCODING_RUNS if label_runs else pb.LABEL_ENCODING_SAMPLES)
        if typed is not None:
            request.pose.CopyFrom(typed)  # typed: joints and angles the server checks field by field
        else:
            request.pose_json = _json_text(pose)
        for name, (vertices, triangles) in (meshes or {}).items():
            request.meshes.add(name=name, vertices=np.asarray(vertices, dtype=float).ravel().tolist(),
                               triangles=np.asarray(triangles, dtype=np.int32).ravel().tolist())
        wait_s = 0.5
        for attempt in range(self._retries + 1):
            header, report, found = None, {}, {}
            parts = {"labels": bytearray(), "ct": bytearray(), "inverse_field": bytearray(),
                     "forward_field": bytearray()}
            try:
                for part in self._stub.Pose(request, timeout=self._timeout,
                                            metadata=self._metadata + (("x-posewarp-rig", rig_id),)):
                    kind = part.WhichOneof("part")
                    if kind == "header":
                        header = part.header
                    elif kind == "labels" and header.label_encoding == pb.LABEL_ENCODING_RUNS:
                        dtype = _sample_dtype(header.label_sample_type)
                        room = (header.label_bytes - len(parts[kind])) // np.dtype(dtype).itemsize
                        parts[kind] += _runs(part.labels.data, dtype, room)
                    elif kind in parts:
                        parts[kind] += getattr(part, kind).data
                    elif kind == "surface":
                        found[part.surface.name] = Surface(
                            np.array(part.surface.vertices).reshape(-1, 3),
                            np.array(part.surface.triangles, dtype=np.int32).reshape(-1, 3))
                    elif kind == "report":
                        report = json.loads(part.report.json)
                break
            except grpc.RpcError as error:
                # gRPC's retry policy stops at a stream's first answer; a replica lost behind a proxy in the middle
                # of one is tried again here (a pose only reads, so repeating it is safe).
                if attempt == self._retries or not _stream_cut(error):
                    raise _error(error.code(), error.details()) from None
                time.sleep(wait_s)
                wait_s = min(8.0, wait_s * 2)
        if header is None or any(len(parts[k]) != n for k, n in (
                ("labels", header.label_bytes), ("ct", header.ct_bytes),
                ("inverse_field", header.inverse_field_bytes), ("forward_field", header.forward_field_bytes))):
            raise DataLossError(grpc.StatusCode.DATA_LOSS, "the server's answer ended early; pose again")
        result = PoseResult(
            _volume(bytes(parts["labels"]), header.grid, _sample_dtype(header.label_sample_type))
            if parts["labels"] else None,
            _volume(bytes(parts["ct"]), header.grid, _sample_dtype(header.ct_sample_type)) if parts["ct"] else None,
            _affine(header.grid), found, report)
        if fields:
            result.inverse_field = _field(bytes(parts["inverse_field"]), header.grid)
            result.forward_field = _field(bytes(parts["forward_field"]), header.source_grid)
        return result


def _stream_cut(error: grpc.RpcError) -> bool:
    """UNAVAILABLE, or a stream that a proxy reset because its replica went away (INTERNAL, RST_STREAM)."""
    return error.code() == grpc.StatusCode.UNAVAILABLE or (
        error.code() == grpc.StatusCode.INTERNAL and "RST_STREAM" in (error.details() or ""))


def _sample_dtype(pixel_type: int):
    """numpy's dtype of a header's sample type (PIXEL_TYPE_UINT8 -> uint8); a type no well-behaved server sends with
    samples (unspecified, or unknown to this client) is DATA_LOSS, as the C++ clients answer it."""
    name = pb.PixelType.Name(pixel_type) if pixel_type in pb.PixelType.values() else "unknown"
    dtype = _DTYPES.get(name[len("PIXEL_TYPE_"):].lower())
    if dtype is None:
        raise DataLossError(grpc.StatusCode.DATA_LOSS, f"the server sent samples of type {name} ({pixel_type}), "
                            "which this client does not know; pose again, or update the client")
    return dtype


def _field(data: bytes, grid) -> np.ndarray:
    """A displacement field sent x fastest, 3 floats per voxel, as an (x, y, z, 3) array."""
    size = tuple(grid.size)
    return np.frombuffer(data, dtype=np.float32).reshape(size[2], size[1], size[0], 3).transpose(2, 1, 0, 3)


def _json_text(value: Any) -> str:
    if value is None:
        return ""
    return value if isinstance(value, str) else json.dumps(value)


def _code(number: int) -> grpc.StatusCode:
    return next((c for c in grpc.StatusCode if c.value[0] == number), grpc.StatusCode.UNKNOWN)
