"""The voxel-to-world affine nibabel gives each NIfTI file named on the
command line (nib.load(path).affine: the sform when its code is set, else
the qform, after nibabel's own header fixes), as JSON
{path: {"affine": 4x4} or {"error": message}}."""
import json
import sys

import nibabel as nib

out = {}
for path in sys.argv[1:]:
    try:
        out[path] = {"affine": nib.load(path).affine.tolist()}
    except Exception as e:  # nibabel refuses the header
        out[path] = {"error": f"{type(e).__name__}: {e}"}
print(json.dumps(out))
