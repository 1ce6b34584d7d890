# posewarp's Orthanc trigger (an orthanc-python plugin script): when a study that holds a CT series and a
# segmentation (a SEG series) becomes stable, it is queued for repositioning; a worker thread runs `posewarp batch`
# on it (fetching the study through Orthanc's own DICOMweb, rigging and posing it on posewarp-server when one is
# configured) and the derived CT series and SEG of every configured pose are stored back into the same study.
#
# The queue is a JSON-lines file: a study queued and not finished when Orthanc stopped or crashed is queued again
# when Orthanc starts. Each study is done once per set of input SEG series (a new segmentation queues it again; the
# derived series posewarp stores, described "posewarp: ...", never do). GET /posewarp/queue lists the queue; POST
# /posewarp/queue with an Orthanc study id queues a study by hand (again, after a failure).
#
# Configuration, in Orthanc's configuration file (see the README's "An Orthanc trigger"):
#   "PythonScript": "/path/to/posewarp_trigger.py",
#   "Posewarp": {
#     "Command": "/usr/bin/posewarp",            # the posewarp command line
#     "Poses": [{"Pose": "/etc/posewarp/hip_30.json", "Method": "cor"}],
#     "Server": "127.0.0.1:50051",                # posewarp-server; empty: rigs built and posed in the worker
#     "TokenFile": "", "TlsCa": "",               # the server's bearer token and CA, when it wants them
#     "PacsUrl": "http://127.0.0.1:8042/dicom-web",  # this Orthanc's DICOMweb root, as the batch reaches it
#     "PacsUser": "", "PacsPasswordFile": "",     # its credentials, when authentication is on
#     "WorkDirectory": "/var/lib/orthanc/posewarp",  # queue file, batch state and logs (default: beside the storage)
#     "TimeoutSeconds": 3600,                     # a batch running longer is stopped and the study marked failed
#     "CtFormat": "series",                       # the posed CT: a CT series, or "enhanced": one Enhanced CT image
#     "SegFormat": "binary"                       # the posed labels: a binary SEG, or "labelmap" (Supplement 243)
#   }
# Logs name studies by Orthanc's resource id only (no patient data).

import json
import os
import queue
import subprocess
import threading
import time

import orthanc

_SETTINGS = {}
_QUEUE = queue.Queue()
_LOCK = threading.Lock()
_STATES = {}  # key -> {"study": orthanc id, "state": queued|running|done|failed, ...}
_STOP = threading.Event()
_WORKER = None


def _log(message):
    orthanc.LogWarning("posewarp: " + message)


def _settings():
    configuration = json.loads(orthanc.GetConfiguration())
    settings = dict(configuration.get("Posewarp", {}))
    storage = configuration.get("StorageDirectory", "OrthancStorage")
    settings.setdefault("Command", "posewarp")
    settings.setdefault("Poses", [])
    settings.setdefault("Server", "")
    settings.setdefault("TokenFile", "")
    settings.setdefault("TlsCa", "")
    port = configuration.get("HttpPort", 8042)
    settings.setdefault("PacsUrl", "http://127.0.0.1:%d/dicom-web" % port)
    settings.setdefault("PacsUser", "")
    settings.setdefault("PacsPasswordFile", "")
    settings.setdefault("WorkDirectory", os.path.join(storage, "posewarp"))
    settings.setdefault("TimeoutSeconds", 3600)
    settings.setdefault("CtFormat", "series")
    settings.setdefault("SegFormat", "binary")
    return settings


_FORMATS = {"CtFormat": ("series", "enhanced"), "SegFormat": ("binary", "labelmap")}


def _format_errors(settings):
    """What is wrong with the configured DICOM formats, in words (empty when they are right)."""
    return ["Posewarp.%s is '%s'; it must be one of %s" % (key, settings[key], ", ".join(allowed))
            for key, allowed in _FORMATS.items() if settings[key] not in allowed]


def _queue_file():
    return os.path.join(_SETTINGS["WorkDirectory"], "queue.jsonl")


def _record(entry):
    """Appends one event to the queue file, flushed to disk before the event counts."""
    entry = dict(entry, time=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
    with open(_queue_file(), "a", encoding="utf-8") as out:
        out.write(json.dumps(entry) + "\n")
        out.flush()
        os.fsync(out.fileno())


def _get(uri):
    return json.loads(orthanc.RestApiGet(uri))


def _inputs_of(study_id):
    """The study's input SEG series (not posewarp's own) if it also holds a CT series, else None."""
    series = _get("/studies/%s/series" % study_id)
    has_ct = False
    segs = []
    for s in series:
        tags = s.get("MainDicomTags", {})
        description = tags.get("SeriesDescription", "")
        if description.startswith("posewarp"):
            continue  # what posewarp stored: never an input
        modality = tags.get("Modality", "")
        if modality == "CT":
            has_ct = True
        elif modality == "SEG":
            segs.append(s["ID"])
    if not has_ct or not segs:
        return None
    return sorted(segs)


def _enqueue(study_id, by_hand=False):
    segs = _inputs_of(study_id)
    if segs is None:
        return "the study has no CT series with a SEG"
    key = study_id + ":" + ",".join(segs)
    with _LOCK:
        state = _STATES.get(key, {}).get("state")
        if state in ("queued", "running") or (state == "done" and not by_hand):
            return "already " + state
        _STATES[key] = {"study": study_id, "state": "queued"}
        _record({"event": "queued", "key": key, "study": study_id})
    _QUEUE.put(key)
    _log("study %s queued for repositioning" % study_id)
    return "queued"


def _batch_command(study_uid, manifest):
    s = _SETTINGS
    command = [s["Command"], "-q", "batch", manifest, "--pacs", s["PacsUrl"],
               "--ct-format", s["CtFormat"], "--seg-format", s["SegFormat"]]
    if s["PacsUser"]:
        command += ["--pacs-user", s["PacsUser"]]
    if s["PacsPasswordFile"]:
        command += ["--pacs-password-file", s["PacsPasswordFile"]]
    if s["Server"]:
        command += ["--server", s["Server"]]
        if s["TokenFile"]:
            command += ["--token-file", s["TokenFile"]]
        if s["TlsCa"]:
            command += ["--tls-ca", s["TlsCa"]]
    return command


def _run(key):
    study_id = _STATES[key]["study"]
    try:
        study = _get("/studies/%s" % study_id)
    except Exception:  # the study was deleted meanwhile
        return "failed", "the study is gone"
    if not _SETTINGS["Poses"]:
        return "failed", "no poses configured (Posewarp.Poses)"
    if _format_errors(_SETTINGS):
        return "failed", "; ".join(_format_errors(_SETTINGS))
    uid = study.get("MainDicomTags", {}).get("StudyInstanceUID", "")
    work = os.path.join(_SETTINGS["WorkDirectory"], study_id)
    os.makedirs(work, exist_ok=True)
    # One row per configured pose: one fetch and one rig for all of them.
    lines = ["id,pacs_study,pose,method,to_pacs"]
    for n, p in enumerate(_SETTINGS["Poses"]):
        lines.append("pose%d,%s,%s,%s,true" % (n, uid, p["Pose"], p.get("Method", "cor")))
    manifest = os.path.join(work, "rows.csv")
    with open(manifest, "w", encoding="utf-8") as out:
        out.write("\n".join(lines) + "\n")
    with open(os.path.join(work, "batch.log"), "ab") as log:
        try:
            code = subprocess.run(_batch_command(uid, manifest), cwd=work, stdout=log, stderr=log,
                                  timeout=_SETTINGS["TimeoutSeconds"]).returncode
        except subprocess.TimeoutExpired:
            return "failed", "the batch ran past %s s" % _SETTINGS["TimeoutSeconds"]
        except OSError as error:
            return "failed", "cannot run %s: %s" % (_SETTINGS["Command"], error.strerror)
    if code != 0:
        return "failed", "posewarp batch exited with %d (see %s)" % (code, os.path.join(work, "batch.log"))
    return "done", ""


def _work():
    while not _STOP.is_set():
        try:
            key = _QUEUE.get(timeout=0.5)
        except queue.Empty:
            continue
        with _LOCK:
            _STATES[key]["state"] = "running"
        started = time.time()
        state, error = _run(key)
        with _LOCK:
            _STATES[key].update(state=state, error=error, seconds=round(time.time() - started, 1))
            _record({"event": state, "key": key, "study": _STATES[key]["study"], "error": error})
        _log("study %s %s in %.1f s%s" % (_STATES[key]["study"], state, time.time() - started,
                                           (": " + error) if error else ""))


def _replay():
    """The queue file read back: studies queued or running when Orthanc stopped are queued again."""
    path = _queue_file()
    if not os.path.exists(path):
        return
    with open(path, encoding="utf-8") as lines:
        for line in lines:
            try:
                entry = json.loads(line)
            except ValueError:
                continue  # a line cut short by a crash
            _STATES[entry["key"]] = {"study": entry["study"], "state": entry["event"], "error": entry.get("error", "")}
    for key, state in _STATES.items():
        if state["state"] == "queued":
            _QUEUE.put(key)
            _log("study %s queued again (unfinished when Orthanc stopped)" % state["study"])


def _on_change(change_type, level, resource_id):
    global _WORKER
    if change_type == orthanc.ChangeType.ORTHANC_STARTED:
        _WORKER = threading.Thread(target=_work, name="posewarp-trigger", daemon=True)
        _WORKER.start()
    elif change_type == orthanc.ChangeType.ORTHANC_STOPPED:
        _STOP.set()
    elif change_type == orthanc.ChangeType.STABLE_STUDY:
        try:
            _enqueue(resource_id)
        except Exception as error:  # never let a study break Orthanc's change loop
            _log("cannot look at study %s: %s" % (resource_id, error))


def _rest_queue(output, uri, **request):
    if request["method"] == "GET":
        with _LOCK:
            items = [dict(state, key=key) for key, state in _STATES.items()]
        output.AnswerBuffer(json.dumps({"items": items}, indent=2), "application/json")
    elif request["method"] == "POST":
        study_id = request["body"].decode("utf-8").strip()
        try:
            answer = _enqueue(study_id, by_hand=True)
        except Exception:
            output.SendHttpStatusCode(404)
            return
        output.AnswerBuffer(json.dumps({"study": study_id, "result": answer}), "application/json")
    else:
        output.SendMethodNotAllowed("GET,POST")


_SETTINGS = _settings()
os.makedirs(_SETTINGS["WorkDirectory"], exist_ok=True)
if not _SETTINGS["Poses"]:
    _log("no poses configured (Posewarp.Poses): studies are queued but nothing is posed")
for _error in _format_errors(_SETTINGS):
    _log(_error + ": studies are queued but nothing is posed until it is fixed")
_replay()
orthanc.RegisterOnChangeCallback(_on_change)
orthanc.RegisterRestCallback("/posewarp/queue", _rest_queue)
_log("trigger ready: %d poses, %s, CT as %s, SEG %s" % (
    len(_SETTINGS["Poses"]), "server " + _SETTINGS["Server"] if _SETTINGS["Server"] else "posed locally",
    _SETTINGS["CtFormat"], _SETTINGS["SegFormat"]))
