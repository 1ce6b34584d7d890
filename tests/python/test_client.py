"""posewarp_client against the real posewarp-server: upload, build and pose the bar phantom and compare with the
CLI's local pose of the same stored rig. Paths come from the environment (set by CTest): POSEWARP_SERVER,
POSEWARP_CLI, POSEWARP_SOURCE_DIR."""
import json
import os
import re
import subprocess

import grpc
import nibabel
import numpy as np
import pytest

from posewarp_client import Client, PosewarpError, _runs, _sample_dtype

SERVER = os.environ["POSEWARP_SERVER"]
CLI = os.environ["POSEWARP_CLI"]
POSE = os.path.join(os.environ["POSEWARP_SOURCE_DIR"], "data", "poses", "bar_bend_90.json")


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    work = tmp_path_factory.mktemp("posewarp")
    subprocess.run([CLI, "--quiet", "phantom", "bar", "-o", str(work / "bar")], check=True)
    server = subprocess.Popen([SERVER, "--listen", "127.0.0.1:0", "--store", str(work / "store")],
                              stdout=subprocess.PIPE, text=True)
    port = re.search(r":(\d+), store", server.stdout.readline()).group(1)
    with Client(f"127.0.0.1:{port}") as client:
        yield work, client
    server.terminate()
    assert server.wait(timeout=60) == 0


def test_upload_build_and_pose_give_what_the_cli_writes(study):
    work, client = study
    labels = client.upload(work / "bar" / "labels.nii.gz", kind="labels")
    ct = client.upload(work / "bar" / "ct.nii.gz", kind="intensity")
    assert re.fullmatch(r"[0-9a-f]{64}", labels)
    stages = []
    with open(work / "bar" / "label_map.json") as f:
        label_map = json.load(f)
    rig = client.build_rig(labels, ct, label_map=label_map, name="bar", progress=lambda s, f: stages.append(s))
    assert {"skeleton", "mesh", "weights"} <= set(stages)
    assert (rig, "bar") in [(r[0], r[1]) for r in client.rigs()]

    posed = client.pose(rig, POSE, method="dqs", surfaces=True)
    subprocess.run([CLI, "--quiet", "pose", str(work / "store" / "rigs" / f"{rig}.rig"), "--pose", POSE, "--method",
                    "dqs", "--labels-out", str(work / "cli_labels.nii.gz"), "--ct-out", str(work / "cli_ct.nii.gz")],
                   check=True)
    cli_labels = nibabel.load(str(work / "cli_labels.nii.gz"))
    assert posed.labels.dtype == cli_labels.get_data_dtype()
    np.testing.assert_array_equal(posed.labels, np.asarray(cli_labels.dataobj))
    np.testing.assert_allclose(posed.affine, cli_labels.affine, atol=1e-4)
    cli_ct = np.asarray(nibabel.load(str(work / "cli_ct.nii.gz")).dataobj, dtype=np.float32)
    np.testing.assert_array_equal(posed.ct, cli_ct)  # stored samples: rounded as the file is
    samples = client.pose(rig, POSE, method="dqs", ct=False, label_runs=False)  # one sample per voxel, not runs
    assert samples.labels.dtype == posed.labels.dtype
    np.testing.assert_array_equal(samples.labels, posed.labels)
    computed = client.pose(rig, POSE, method="dqs", samples="computed", fields=True,
                           meshes={"needle": (posed.surfaces[next(iter(posed.surfaces))][0][:4], [[0, 1, 2]])})
    assert computed.ct.dtype == np.float32 and computed.labels.dtype == np.int32
    np.testing.assert_allclose(computed.ct, cli_ct, atol=0.51)
    assert computed.inverse_field.shape == computed.labels.shape + (3,)
    assert "needle" in computed.surfaces and computed.surfaces["needle"][0].shape == (4, 3)
    assert posed.report["method"] == "dqs"
    assert len(posed.surfaces) > 0
    fem = client.pose(rig, POSE, method="fem", ct=False)
    assert fem.report["method"] == "fem" and "fem" in fem.report["stage_seconds"]
    assert fem.labels.shape == posed.labels.shape
    assert set(np.unique(fem.labels)) <= set(np.unique(posed.labels)) | {0}
    # The fem solve's options reach the server: 1 iteration moves less tissue than 100; out of range is refused.
    steady = client.pose(rig, POSE, method="fem", labels=False, ct=False)
    short = client.pose(rig, POSE, method="fem", labels=False, ct=False, fem_iterations=1)
    assert steady.report["moved_joints"] and short.report["moved_joints"] != steady.report["moved_joints"]
    with pytest.raises(PosewarpError) as too_many:
        client.pose(rig, POSE, method="fem", labels=False, ct=False, fem_iterations=20000)
    assert too_many.value.code == grpc.StatusCode.INVALID_ARGUMENT and "max_iterations" in str(too_many.value)


def test_label_runs_decode_and_a_malformed_chunk_is_data_loss():
    def runs(*pairs, value="<i2"):
        return np.array(list(pairs), dtype=[("value", value), ("count", "<u4")]).tobytes()

    assert np.frombuffer(_runs(runs((3, 2), (-1, 3)), np.int16), np.int16).tolist() == [3, 3, -1, -1, -1]
    assert np.frombuffer(_runs(runs((200, 4), value="u1"), np.uint8), np.uint8).tolist() == [200] * 4
    for chunk in (runs((3, 2))[:-1], runs((3, 2), (4, 0))):  # a torn pair, a run of none
        with pytest.raises(PosewarpError) as malformed:
            _runs(chunk, np.int16)
        assert malformed.value.code == grpc.StatusCode.DATA_LOSS
    # Runs past the size the header gave (here 4 billion samples from 6 bytes): refused before any allocation.
    assert np.frombuffer(_runs(runs((7, 5)), np.int16, room=5), np.int16).tolist() == [7] * 5
    with pytest.raises(PosewarpError) as past:
        _runs(runs((7, 2**32 - 1)), np.int16, room=1000)
    assert past.value.code == grpc.StatusCode.DATA_LOSS
    # Samples of no type, or of one this client does not know.
    for pixel_type in (0, 999):
        with pytest.raises(PosewarpError) as untyped:
            _sample_dtype(pixel_type)
        assert untyped.value.code == grpc.StatusCode.DATA_LOSS


def test_refusals_carry_their_codes(study):
    _, client = study
    with pytest.raises(PosewarpError) as unknown:
        client.pose("0" * 64, {"joints": {}})
    assert unknown.value.code == grpc.StatusCode.NOT_FOUND
    with pytest.raises(PosewarpError) as bad_id:
        client.pose("../etc/passwd", {"joints": {}})
    assert bad_id.value.code == grpc.StatusCode.INVALID_ARGUMENT


def test_an_array_uploads_with_its_affine(study):
    _, client = study
    array = np.zeros((8, 7, 6), dtype=np.uint8)
    array[2:5, 2:5, 2:4] = 1
    affine = np.diag([1.5, 1.5, 2.5, 1.0])
    volume_id = client.upload(array=array, affine=affine, kind="labels")
    assert re.fullmatch(r"[0-9a-f]{64}", volume_id)
    assert client.upload(array=array, affine=affine, kind="labels") == volume_id  # stored once


def test_a_token_protected_server_needs_the_clients_token(tmp_path):
    (tmp_path / "tokens").write_text("python-token\n")
    server = subprocess.Popen([SERVER, "--listen", "127.0.0.1:0", "--store", str(tmp_path / "store"),
                               "--token-file", str(tmp_path / "tokens")], stdout=subprocess.PIPE, text=True)
    try:
        port = re.search(r":(\d+), store", server.stdout.readline()).group(1)
        with Client(f"127.0.0.1:{port}") as anonymous:
            with pytest.raises(PosewarpError) as refused:
                anonymous.rigs()
            assert refused.value.code == grpc.StatusCode.UNAUTHENTICATED
        with Client(f"127.0.0.1:{port}", token="python-token") as client:
            assert client.rigs() == []
    finally:
        server.terminate()
        assert server.wait(timeout=60) == 0
