"""Rebuild the default face mesh, meshes/face.obj, from the public-domain portrait of
Grace Hopper that matplotlib ships (or from any photo given on the command line).

    python scripts/build_face_mesh.py                 # -> meshes/face.obj
    python scripts/build_face_mesh.py photo.jpg -o my_face.obj [--no-symmetrise]

Needs MediaPipe (pip install -e '.[photo]'; `make mesh` does it). See facesim/face/photo.py
for the steps and meshes/NOTICE for the provenance.
"""

import argparse
import sys
from pathlib import Path

from facesim.errors import FacesimError
from facesim.face.photo import mesh_from_photo

ROOT = Path(__file__).resolve().parent.parent


def hopper_portrait() -> Path:
    import matplotlib.cbook

    return Path(matplotlib.cbook.get_sample_data("grace_hopper.jpg", asfileobj=False))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("photo", nargs="?", type=Path, help="portrait (default: matplotlib's grace_hopper.jpg)")
    parser.add_argument("-o", "--output", type=Path, default=ROOT / "meshes" / "face.obj")
    parser.add_argument("--no-symmetrise", dest="symmetric", action="store_false")
    args = parser.parse_args()
    try:
        mesh = mesh_from_photo(args.photo or hopper_portrait(), args.output, symmetric=args.symmetric)
    except FacesimError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    print(f"wrote {args.output}: {mesh.vertex_count} vertices, {len(mesh.faces)} triangles")
    return 0


if __name__ == "__main__":
    sys.exit(main())
