"""posewarp match against elastix (rigid + B-spline) on one pair: rest volume -> target; prints a markdown table.

For each bone label larger than --min-ml in the rest volume: Dice of that label between each tool's result on the
target's grid and the target, and the result's bone rigidity: over the bone's voxels x on the target grid, the rest
point T(x) each tool maps them to (posewarp: the inverse field of `posewarp pose --grid-like TARGET --field-out`;
elastix: transformix's deformation field; both x + u(x), LPS mm) is fitted with the best rigid transform (Kabsch) and
the RMS and largest distance from it are given in mm. Times are wall clock, reading the inputs included.
Run with the bench venv (scripts/bench-env: SimpleITK's elastix build). Usage: see --help; scripts/match-vs-elastix
runs it on the body phantom and the real sample.
"""
import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np
import SimpleITK as sitk


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--posewarp", default="build/clients/cli/posewarp", help="posewarp binary")
    p.add_argument("--rig", required=True)
    p.add_argument("--rest-labels", required=True, help="labels the rig was built from")
    p.add_argument("--rest-ct", required=True, help="CT the rig was built from")
    p.add_argument("--label-map", required=True, help="posewarp label map JSON (bones: role 'bone')")
    p.add_argument("--target-labels", required=True)
    p.add_argument("--target-ct", required=True)
    p.add_argument("--out", required=True, help="working directory for this pair")
    p.add_argument("--name", default="", help="pair's name in the table's title")
    p.add_argument("--min-ml", type=float, default=5.0, help="bones at least this large in the rest volume")
    p.add_argument("--elastix-shrink", type=int, default=1,
                   help="register on copies of both CTs binned by this factor per axis (labels and fields are "
                        "still resampled on the full target grid)")
    p.add_argument("--elastix-iterations", type=int, default=0,
                   help="MaximumNumberOfIterations per resolution for both maps (0: elastix's default, 256)")
    p.add_argument("--elastix-param", action="append", default=[], metavar="KEY=VALUE",
                   help="set an elastix parameter in both maps (repeatable), e.g. "
                        "ASGDParameterEstimationMethod=DisplacementDistribution")
    p.add_argument("--keep-fields", action="store_true", help="keep the displacement fields in --out")
    return p.parse_args()


def bone_labels(label_map_path, rest_labels, voxel_ml, min_ml):
    """(value, name, rest ml) of the map's bones larger than min_ml in the rest labels, by value."""
    bones = {l["value"]: l["name"] for l in json.load(open(label_map_path))["labels"] if l.get("role") == "bone"}
    counts = np.bincount(rest_labels.ravel(), minlength=256)
    return [(v, bones[v], counts[v] * voxel_ml) for v in sorted(bones) if v < counts.size
            and counts[v] * voxel_ml > min_ml]


def physical_points(image, flat_index):
    """LPS mm of the voxels at these flat (numpy C-order: z, y, x) indices of a SimpleITK image's grid; (n, 3)."""
    nx, ny, _ = image.GetSize()
    ijk = np.stack([flat_index % nx, (flat_index // nx) % ny, flat_index // (nx * ny)], axis=1).astype(np.float64)
    direction = np.array(image.GetDirection()).reshape(3, 3)
    return np.asarray(image.GetOrigin()) + (ijk * np.asarray(image.GetSpacing())) @ direction.T


def rigid_residuals(x, y):
    """Distances (mm) of y from the best rigid map of x onto it (Kabsch, least squares); x, y (n, 3)."""
    cx, cy = x.mean(axis=0), y.mean(axis=0)
    u, _, vt = np.linalg.svd((x - cx).T @ (y - cy))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return np.linalg.norm((x - cx) @ r.T + cy - y, axis=1)


def dice(result, target, value):
    in_result, in_target = result == value, target == value
    total = np.count_nonzero(in_result) + np.count_nonzero(in_target)
    return 2.0 * np.count_nonzero(in_result & in_target) / total if total else float("nan")


def evaluate(result, target, field, grid, bones, rest_labels, rest_image):
    """Per bone: Dice, rigidity RMS and max (mm), and the share of its voxels whose rest point lies in the same rest
    bone (a check of the field's convention). result, target: label arrays on the target grid (z, y, x);
    field: (z, y, x, 3) float32 displacement, x + u(x) = rest point."""
    flat_result, flat_target, flat_field = result.ravel(), target.ravel(), field.reshape(-1, 3)
    rest_direction_inv = np.linalg.inv(np.array(rest_image.GetDirection()).reshape(3, 3))
    rest_origin, rest_spacing = np.asarray(rest_image.GetOrigin()), np.asarray(rest_image.GetSpacing())
    rows = {}
    for value, name, _ in bones:
        overlap = dice(flat_result, flat_target, value)
        index = np.flatnonzero(flat_result == value)
        if index.size < 4:
            rows[value] = (overlap, float("nan"), float("nan"), float("nan"))
            continue
        x = physical_points(grid, index)
        rest_points = x + flat_field[index].astype(np.float64)
        residual = rigid_residuals(x, rest_points)
        ijk = np.rint((rest_points - rest_origin) @ rest_direction_inv.T / rest_spacing).astype(np.int64)
        inside = np.all((ijk >= 0) & (ijk < np.asarray(rest_labels.shape[::-1])), axis=1)
        same = np.zeros(index.size, dtype=bool)
        same[inside] = rest_labels[ijk[inside, 2], ijk[inside, 1], ijk[inside, 0]] == value
        rows[value] = (overlap, float(np.sqrt(np.mean(residual ** 2))), float(residual.max()), float(same.mean()))
    return rows


def run_posewarp(args, work):
    pose, report, labels = (os.path.join(work, f) for f in ("pose.json", "match_report.json", "posewarp_labels.nii.gz"))
    start = time.perf_counter()
    subprocess.run([args.posewarp, "--quiet", "match", args.rig, "--target-labels", args.target_labels, "-o", pose,
                    "--report", report, "--labels-out", labels], check=True)
    wall = time.perf_counter() - start
    field = os.path.join(work, "posewarp_field.mha")
    subprocess.run([args.posewarp, "--quiet", "pose", args.rig, "--pose", pose, "--grid-like", args.target_labels,
                    "--field-out", field], check=True)
    return labels, field, wall, json.load(open(report))


def parameter_maps(args):
    maps = [sitk.GetDefaultParameterMap("rigid"), sitk.GetDefaultParameterMap("bspline")]
    changes = ["WriteResultImage false (the registration's own resampled CT is not used)"]
    if args.elastix_iterations:
        for m in maps:
            m["MaximumNumberOfIterations"] = [str(args.elastix_iterations)]
        changes.append("MaximumNumberOfIterations %d (default 256)" % args.elastix_iterations)
    for setting in args.elastix_param:
        key, _, value = setting.partition("=")
        for m in maps:
            m[key] = value.split()
        changes.append("%s %s" % (key, value))
    for m in maps:
        m["WriteResultImage"] = ["false"]
    vector = sitk.VectorOfParameterMap()
    for m in maps:
        vector.append(m)
    return vector, changes


def transformix(maps, moving, log, field=False):
    """The rest labels through these transform parameter maps, or with field=True the deformation field (fixed grid,
    x + u(x) = moving point, LPS mm) as a (z, y, x, 3) float32 array."""
    vector = sitk.VectorOfParameterMap()
    for m in maps:
        vector.append(m)
    filter = sitk.TransformixImageFilter()
    filter.SetMovingImage(moving)
    filter.SetTransformParameterMap(vector)
    filter.SetOutputDirectory(log)
    filter.LogToConsoleOff()
    if field:
        filter.ComputeDeformationFieldOn()
    filter.Execute()
    result = filter.GetDeformationField() if field else filter.GetResultImage()
    for name in os.listdir(log):  # transformix writes its results too: we have them in memory
        if name.startswith(("result", "deformationField")) and name.endswith(".nii"):
            os.remove(os.path.join(log, name))
    if field:
        return sitk.GetArrayFromImage(result).astype(np.float32, copy=False)
    return sitk.GetArrayFromImage(result).astype(np.uint8)


def run_elastix(args, work, target_grid):
    """Registers the rest CT (moving) onto the target CT (fixed); returns the labels on the target grid after the
    rigid stage and after both, the field, the times and the changes from elastix's defaults."""
    start = time.perf_counter()
    fixed = sitk.ReadImage(args.target_ct, sitk.sitkFloat32)
    moving = sitk.ReadImage(args.rest_ct, sitk.sitkFloat32)
    if args.elastix_shrink > 1:
        fixed = sitk.BinShrink(fixed, [args.elastix_shrink] * 3)
        moving = sitk.BinShrink(moving, [args.elastix_shrink] * 3)
    maps, changes = parameter_maps(args)
    log = os.path.join(work, "elastix")
    os.makedirs(log, exist_ok=True)
    elastix = sitk.ElastixImageFilter()
    elastix.SetFixedImage(fixed)
    elastix.SetMovingImage(moving)
    elastix.SetParameterMap(maps)
    elastix.SetOutputDirectory(log)
    elastix.LogToConsoleOff()
    elastix.LogToFileOn()
    try:
        elastix.Execute()
    except RuntimeError:
        # A grown target grid can start with more than elastix's RequiredRatioOfValidSamples (0.25) of the fixed
        # samples outside the moving image; elastix then stops at once. Once more with a lower ratio, said in the table.
        if "Too many samples map outside moving image buffer" not in open(os.path.join(log, "elastix.log")).read():
            raise
        retry = sitk.VectorOfParameterMap()  # (iterating a VectorOfParameterMap gives copies)
        for i in range(len(maps)):
            m = maps[i]
            m["RequiredRatioOfValidSamples"] = ["0.05"]
            retry.append(m)
        maps = retry
        changes.append("RequiredRatioOfValidSamples 0.05 (elastix stopped at its 0.25: 'Too many samples map outside "
                       "moving image buffer')")
        elastix.SetParameterMap(maps)
        elastix.Execute()
    transform = [elastix.GetTransformParameterMap(i) for i in range(len(maps))]
    del fixed, moving, elastix
    registration = time.perf_counter() - start

    # The results on the full target grid, labels nearest-neighbour (B-spline order 0) in their own type. elastix's
    # Direction is column by column (ITK's GetDirection() row by row).
    grid = {"Size": [float(s) for s in target_grid.GetSize()], "Spacing": list(target_grid.GetSpacing()),
            "Origin": list(target_grid.GetOrigin()),
            "Direction": list(np.array(target_grid.GetDirection()).reshape(3, 3).T.ravel())}
    for m in transform:
        if args.elastix_shrink == 1:
            for key, values in grid.items():
                if not np.allclose([float(v) for v in m[key]], values, atol=1e-4):
                    sys.exit("elastix's %s %s is not the target's %s" % (key, m[key], values))
        m["Size"] = [str(s) for s in target_grid.GetSize()]
        for key in ("Spacing", "Origin", "Direction"):
            m[key] = ["%.17g" % v for v in grid[key]]
        m["FinalBSplineInterpolationOrder"] = ["0"]
        m["ResultImagePixelType"] = ["unsigned char"]
    start = time.perf_counter()
    rest_labels = sitk.ReadImage(args.rest_labels, sitk.sitkUInt8)
    labels = transformix(transform, rest_labels, log)
    resample = time.perf_counter() - start
    image = sitk.GetImageFromArray(labels)
    image.CopyInformation(target_grid)
    sitk.WriteImage(image, os.path.join(work, "elastix_labels.nii.gz"))
    del image
    rigid_labels = transformix(transform[:1], rest_labels, log)
    field = transformix(transform, rest_labels, log, field=True)
    return labels, rigid_labels, field, registration, resample, changes


def read_array(path, pixel):
    image = sitk.ReadImage(path, pixel)
    return sitk.GetArrayFromImage(image), image


def same_grid(a, b):
    return (a.GetSize() == b.GetSize() and np.allclose(a.GetOrigin(), b.GetOrigin(), atol=1e-3)
            and np.allclose(a.GetSpacing(), b.GetSpacing(), atol=1e-5)
            and np.allclose(a.GetDirection(), b.GetDirection(), atol=1e-5))


def main():
    args = parse_args()
    work = os.path.abspath(args.out)
    os.makedirs(work, exist_ok=True)
    target, target_grid = read_array(args.target_labels, sitk.sitkUInt8)
    rest, rest_image = read_array(args.rest_labels, sitk.sitkUInt8)
    voxel_ml = float(np.prod(rest_image.GetSpacing())) / 1000.0
    bones = bone_labels(args.label_map, rest, voxel_ml, args.min_ml)

    pw_labels, pw_field, pw_wall, pw_report = run_posewarp(args, work)
    result, result_grid = read_array(pw_labels, sitk.sitkUInt8)
    field, field_grid = read_array(pw_field, sitk.sitkVectorFloat32)
    if not (same_grid(result_grid, target_grid) and same_grid(field_grid, target_grid)):
        sys.exit("posewarp's labels or field are not on the target's grid")
    results = {"posewarp": evaluate(result, target, field, target_grid, bones, rest, rest_image)}
    del result, field
    if not args.keep_fields:
        for path in (pw_field, pw_field.replace(".mha", "_forward.mha")):
            if os.path.exists(path):
                os.remove(path)

    result, rigid_result, field, el_registration, el_resample, changes = run_elastix(args, work, target_grid)
    results["elastix"] = evaluate(result, target, field, target_grid, bones, rest, rest_image)
    del result, field
    rigid_dice = {value: dice(rigid_result, target, value) for value, _, _ in bones}
    del rigid_result

    print_table(args, bones, results, rigid_dice, target_grid, pw_wall, pw_report, el_registration, el_resample,
                changes)
    names = ("dice", "rigidity_rms_mm", "rigidity_max_mm", "same_rest_bone")
    json.dump({"pair": args.name,
               "bones": [{"label": v, "name": n, "rest_ml": ml, "elastix_rigid_stage_dice": rigid_dice[v],
                          **{t: dict(zip(names, results[t][v])) for t in results}} for v, n, ml in bones],
               "posewarp_seconds": {"wall": pw_wall, "match": pw_report.get("seconds")},
               "elastix_seconds": {"registration": el_registration, "transformix_labels": el_resample},
               "elastix_changes": changes, "elastix_shrink": args.elastix_shrink},
              open(os.path.join(work, "comparison.json"), "w"), indent=1)


def print_table(args, bones, results, rigid_dice, grid, pw_wall, pw_report, el_registration, el_resample, changes):
    pw, el = results["posewarp"], results["elastix"]
    names = {value: name for value, name, _ in bones}
    print("\n#### %s (target grid %s, %.1fM voxels; %d bones over %g ml)\n" % (
        args.name or os.path.basename(args.target_labels), " x ".join(map(str, grid.GetSize())),
        np.prod(grid.GetSize()) / 1e6, len(bones), args.min_ml))
    print("| bone | rest ml | Dice posewarp | Dice elastix | (elastix rigid stage) | rigidity posewarp RMS / max mm "
          "| rigidity elastix RMS / max mm |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for value, name, ml in bones:
        print("| %s | %.0f | %.3f | %.3f | (%.3f) | %.2f / %.2f | %.2f / %.2f |" % (
            name, ml, pw[value][0], el[value][0], rigid_dice[value], pw[value][1], pw[value][2], el[value][1],
            el[value][2]))

    def smallest(dices):
        value = min(dices, key=lambda v: dices[v])
        return "%.3f %s, mean %.3f" % (dices[value], names[value], np.mean(list(dices.values())))

    def worst(rows):
        rms, largest = (max(rows, key=lambda v: rows[v][i]) for i in (1, 2))
        return "%.2f %s / %.2f %s" % (rows[rms][1], names[rms], rows[largest][2], names[largest])

    print("| **smallest Dice** | | %s | %s | (%s) | | |" % (
        smallest({v: r[0] for v, r in pw.items()}), smallest({v: r[0] for v, r in el.items()}), smallest(rigid_dice)))
    print("| **worst rigidity** (RMS / max) | | | | | %s | %s |" % (worst(pw), worst(el)))
    match_s = pw_report.get("seconds")
    print("| **time** | | %.1f s (match %s s) | %.1f s (registration %.1f s, transformix labels %.1f s) | | | |" % (
        pw_wall, "%.2f" % match_s if match_s is not None else "?", el_registration + el_resample, el_registration,
        el_resample))
    checks = {t: 100 * np.mean([r[3] for r in results[t].values()]) for t in results}
    shrink = ", both CTs binned %dx per axis for the registration" % args.elastix_shrink \
        if args.elastix_shrink > 1 else ""
    print("\nelastix: GetDefaultParameterMap('rigid') + GetDefaultParameterMap('bspline'), moving = rest CT, fixed = "
          "target CT%s; changed: %s; labels by transformix on the full target grid, FinalBSplineInterpolationOrder 0. "
          "posewarp's time: `posewarp match` with --labels-out, the rig's loading included; elastix's: reading both "
          "CTs, registration, reading the rest labels and transformix. Field check (a result bone voxel's rest point in "
          "the same rest bone, mean over bones): posewarp %.1f%%, elastix %.1f%%." % (
              shrink, "; ".join(changes), checks["posewarp"], checks["elastix"]))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
