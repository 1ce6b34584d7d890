"""posewarp_client: upload a study, build its rig and pose it on a posewarp-server, with numpy arrays back.

    from posewarp_client import Client
    client = Client("127.0.0.1:50051")
    labels = client.upload("seg.nii.gz", kind="labels")
    ct = client.upload("ct.nii.gz", kind="intensity")
    rig = client.build_rig(labels, ct, preset="totalsegmentator", progress=print)
    posed = client.pose(rig, {"joints": {"hip_left": {"angles_deg": [30, 0, 0]}}}, method="cor")
    posed.labels, posed.ct, posed.affine, posed.report      # numpy (x, y, z) arrays, RAS affine, dict

Stubs come from the build (build/clients/python/generated on PYTHONPATH); runtime: Debian's python3-grpcio,
python3-protobuf and python3-numpy (python3-nibabel to upload arrays).
"""
import hashlib
import json
import os
import time

import grpc
import numpy as np

from posewarp.v1 import posewarp_pb2 as pb
from posewarp.v1 import posewarp_pb2_grpc as rpc

__all__ = ["Client", "PoseResult", "PosewarpError"]

_CHUNK = 1 << 20
_FORMATS = {".nii.gz": pb.FILE_FORMAT_NIFTI_GZ, ".nii": pb.FILE_FORMAT_NIFTI, ".nrrd": pb.FILE_FORMAT_NRRD,
            ".mha": pb.FILE_FORMAT_MHA}
_METHODS = {"cor": pb.METHOD_COR, "dqs": pb.METHOD_DQS, "lbs": pb.METHOD_LBS, "fem": pb.METHOD_FEM}
_DTYPES = {"uint8": np.uint8, "int8": np.int8, "uint16": np.uint16, "int16": np.int16, "uint32": np.uint32,
           "int32": np.int32, "float32": np.float32, "float64": np.float64}


class PosewarpError(RuntimeError):
    """A call the server refused: .code is the gRPC status code, the message says what to fix."""

    def __init__(self, code, message):
        super().__init__(f"{code.name}: {message}")
        self.code = code


class PoseResult:
    """A posed study: labels and ct as (x, y, z) numpy arrays (None when not asked for), the RAS affine of their
    grid (as nibabel uses it), the posed surfaces as {name: (vertices, triangles)} in LPS mm, the report, and with
    fields=True inverse_field and forward_field as (x, y, z, 3) arrays."""

    def __init__(self, labels, ct, affine, surfaces, report):
        self.labels, self.ct, self.affine, self.surfaces, self.report = labels, ct, affine, surfaces, report
        self.inverse_field = self.forward_field = None


def _affine(grid):
    """The NIfTI (RAS) affine of a grid in LPS millimetres."""
    direction = np.array(grid.direction, dtype=float).reshape(3, 3)
    lps = np.eye(4)
    lps[:3, :3] = direction @ np.diag(np.array(grid.spacing, dtype=float))
    lps[:3, 3] = np.array(grid.origin, dtype=float)
    return np.diag([-1.0, -1.0, 1.0, 1.0]) @ lps


def _volume(data, grid, dtype):
    """Voxels sent x fastest as an (x, y, z) array."""
    size = tuple(grid.size)
    return np.frombuffer(data, dtype=dtype).reshape(size[2], size[1], size[0]).transpose(2, 1, 0)


def _runs(data, dtype, room=None):
    """The samples of a chunk of runs: (value as dtype, count as uint32) pairs, little-endian, packed. A chunk no
    well-behaved server sends (a torn pair, a run of none, more samples than `room` left of the size its header gave)
    is DATA_LOSS, as the C++ clients answer it: nothing is allocated for it."""
    pair = np.dtype([("value", np.dtype(dtype).newbyteorder("<")), ("count", "<u4")])
    if len(data) % pair.itemsize:
        raise PosewarpError(grpc.StatusCode.DATA_LOSS, f"the server's labels end inside a run ({len(data)} bytes "
                            f"of {pair.itemsize}-byte runs); pose again")
    pairs = np.frombuffer(data, dtype=pair)
    if (pairs["count"] == 0).any():
        raise PosewarpError(grpc.StatusCode.DATA_LOSS, "the server's labels hold a run of no samples; pose again")
    total = int(pairs["count"].sum(dtype=np.uint64))
    if room is not None and total > room:
        raise PosewarpError(grpc.StatusCode.DATA_LOSS, f"the server's labels run {total} samples past the "
                            f"{room} its header left room for; pose again")
    return np.repeat(pairs["value"], pairs["count"]).tobytes()


class Client:
    def __init__(self, address, timeout_s=600.0, token=None, tls_ca=None, retries=3):
        """token: the server's bearer token (or None); tls_ca: path of the CA certificate (PEM) of a TLS server;
        retries: calls answered UNAVAILABLE (a server restarting) are tried again this many times, 0.5 s apart and
        doubling (gRPC's own retry policy, which stops at a stream's first answer; a pose whose stream a proxy cut
        in mid-answer, its replica gone, is posed again by pose() itself)."""
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
        self._metadata = (("authorization", "Bearer " + token.strip()),) if token else ()

    def close(self):
        self._channel.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _call(self, method, request):
        try:
            return method(request, timeout=self._timeout, metadata=self._metadata)
        except grpc.RpcError as error:
            raise PosewarpError(error.code(), error.details()) from None

    def upload(self, path=None, kind="labels", array=None, affine=None):
        """Uploads a volume file (.nii.gz, .nii, .nrrd, .mha), or a numpy array with its RAS affine (written as
        NIfTI with nibabel); returns the volume id."""
        if array is not None:
            import nibabel  # only needed for arrays
            image = nibabel.Nifti1Image(np.asarray(array), affine if affine is not None else np.eye(4))
            data, fmt = image.to_bytes(), pb.FILE_FORMAT_NIFTI
        else:
            fmt = next((f for ext, f in _FORMATS.items() if str(path).endswith(ext)), None)
            if fmt is None:
                raise ValueError(f"{path}: the server takes .nii.gz, .nii, .nrrd or .mha files")
            with open(path, "rb") as f:
                data = f.read()
        header = pb.UploadVolumeHeader(
            kind=pb.VOLUME_KIND_LABELS if kind == "labels" else pb.VOLUME_KIND_INTENSITY, format=fmt,
            size_bytes=len(data), sha256=hashlib.sha256(data).hexdigest())

        def parts():
            yield pb.UploadVolumeRequest(header=header)
            for offset in range(0, len(data), _CHUNK):
                yield pb.UploadVolumeRequest(chunk=data[offset:offset + _CHUNK])

        return self._call(self._stub.UploadVolume, parts()).id

    def build_rig(self, labels_id, ct_id="", preset="", label_map=None, rig_spec=None, name="", progress=None):
        """Builds (or finds) the rig of uploaded volumes; progress(stage, fraction) is called as it runs. Returns
        the rig id; raises PosewarpError when the build fails."""
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
            raise PosewarpError(error.code(), error.details()) from None
        if operation.state != pb.Operation.SUCCEEDED:
            raise PosewarpError(grpc.StatusCode.UNKNOWN if not operation.error_code else
                                _code(operation.error_code), operation.error_message or "the build did not succeed")
        return operation.rig_id

    def rigs(self):
        """[(id, name, size_bytes, created)] of the rigs the server holds."""
        found, token = [], ""
        while True:
            page = self._call(self._stub.ListRigs, pb.ListRigsRequest(page_size=1000, page_token=token))
            found += [(r.id, r.name, r.size_bytes, r.created) for r in page.rigs]
            token = page.next_page_token
            if not token:
                return found

    def pose(self, rig_id, pose, method="cor", grid="input", labels=True, ct=True, surfaces=False,
             samples="stored", fields=False, meshes=None, fem_iterations=0, fem_volume_weight=0.0, label_runs=True):
        """Poses a rig: `pose` is the CLI's pose JSON as a dict (or a path to one).

        method: "cor" (centres of rotation, the default), "dqs", "lbs" or "fem" (CoR refined by the soft tissue's
        volume-preserving steady state: slower, folds less tissue at bent joints). With "fem", fem_iterations (1 to
        10000, default 100: more converges further and takes longer) and fem_volume_weight (how much more keeping
        volume counts than keeping shape, default 100) tune its solve; 0 keeps the server's default.

        samples: "stored" gives each volume in the study's own type (the CT rounded as a file stores it, the fewest
        bytes); "computed" gives int32 labels and float32 CT as computed. fields: also the inverse (output grid) and
        forward (study grid) displacement fields, (x, y, z, 3) float32 arrays in LPS mm. meshes: {name: (vertices,
        triangles)} of your own in rest space (LPS mm), posed and returned among the surfaces. label_runs: the labels
        travel as runs of equal values (a fraction of their samples' bytes) and come back as the same array."""
        if isinstance(pose, (str, os.PathLike)) and os.path.exists(pose):
            with open(pose) as f:
                pose = json.load(f)
        if samples not in ("stored", "computed"):
            raise ValueError("samples is 'stored' or 'computed'")
        request = pb.PoseRequest(rig_id=rig_id, pose_json=_json_text(pose), method=_METHODS[method],
                                 grid=pb.GRID_POLICY_GROW if grid == "grow" else pb.GRID_POLICY_INPUT,
                                 want_labels=labels, want_ct=ct, want_surfaces=surfaces or bool(meshes),
                                 samples=pb.SAMPLE_TYPE_STORED if samples == "stored" else pb.SAMPLE_TYPE_COMPUTED,
                                 want_fields=fields,
                                 fem=pb.FemOptions(max_iterations=fem_iterations, volume_weight=fem_volume_weight),
                                 label_encoding=pb.LABEL_ENCODING_RUNS if label_runs else pb.LABEL_ENCODING_SAMPLES)
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
                        found[part.surface.name] = (np.array(part.surface.vertices).reshape(-1, 3),
                                                    np.array(part.surface.triangles, dtype=np.int32).reshape(-1, 3))
                    elif kind == "report":
                        report = json.loads(part.report.json)
                break
            except grpc.RpcError as error:
                # gRPC's retry policy stops at a stream's first answer; a replica lost behind a proxy in the middle
                # of one is tried again here (a pose only reads, so repeating it is safe).
                if attempt == self._retries or not _stream_cut(error):
                    raise PosewarpError(error.code(), error.details()) from None
                time.sleep(wait_s)
                wait_s = min(8.0, wait_s * 2)
        if header is None or any(len(parts[k]) != n for k, n in (
                ("labels", header.label_bytes), ("ct", header.ct_bytes),
                ("inverse_field", header.inverse_field_bytes), ("forward_field", header.forward_field_bytes))):
            raise PosewarpError(grpc.StatusCode.DATA_LOSS, "the server's answer ended early; pose again")
        result = PoseResult(
            _volume(bytes(parts["labels"]), header.grid, _sample_dtype(header.label_sample_type))
            if parts["labels"] else None,
            _volume(bytes(parts["ct"]), header.grid, _sample_dtype(header.ct_sample_type)) if parts["ct"] else None,
            _affine(header.grid), found, report)
        if fields:
            result.inverse_field = _field(bytes(parts["inverse_field"]), header.grid)
            result.forward_field = _field(bytes(parts["forward_field"]), header.source_grid)
        return result


def _stream_cut(error):
    """UNAVAILABLE, or a stream that a proxy reset because its replica went away (INTERNAL, RST_STREAM)."""
    return error.code() == grpc.StatusCode.UNAVAILABLE or (
        error.code() == grpc.StatusCode.INTERNAL and "RST_STREAM" in (error.details() or ""))


def _sample_dtype(pixel_type):
    """numpy's dtype of a header's sample type (PIXEL_TYPE_UINT8 -> uint8); a type no well-behaved server sends with
    samples (unspecified, or unknown to this client) is DATA_LOSS, as the C++ clients answer it."""
    name = pb.PixelType.Name(pixel_type) if pixel_type in pb.PixelType.values() else "unknown"
    dtype = _DTYPES.get(name[len("PIXEL_TYPE_"):].lower())
    if dtype is None:
        raise PosewarpError(grpc.StatusCode.DATA_LOSS, f"the server sent samples of type {name} ({pixel_type}), "
                            "which this client does not know; pose again, or update the client")
    return dtype


def _field(data, grid):
    """A displacement field sent x fastest, 3 floats per voxel, as an (x, y, z, 3) array."""
    size = tuple(grid.size)
    return np.frombuffer(data, dtype=np.float32).reshape(size[2], size[1], size[0], 3).transpose(2, 1, 0, 3)


def _json_text(value):
    if value is None:
        return ""
    return value if isinstance(value, str) else json.dumps(value)


def _code(number):
    return next((c for c in grpc.StatusCode if c.value[0] == number), grpc.StatusCode.UNKNOWN)
