"""A .blend saved before the panel's properties were generated from the settings'
declarations (``golden/object_settings.blend``, made by
``golden/make_object_settings_blend.py``) still finds every value under the generated
properties: the RNA names, types and enum numbers were kept."""

import json
import subprocess
import sys

from conftest import ENABLE_IN_FRESH_PROCESS, REPO

sys.path.insert(0, str(REPO / "tests" / "golden"))
from make_object_settings_blend import GOLDEN, VALUES  # noqa: E402

READ = f"""
import json
with bpy.data.libraries.load({str(GOLDEN)!r}, link=False) as (source, loaded):
    loaded.objects = ["Probe"]
settings = bpy.data.objects["Probe"].vdnif
print(json.dumps({{name: getattr(settings, name) for name in {sorted(VALUES)!r}}}))
"""


def test_a_blend_saved_before_the_declarations_keeps_its_settings():
    done = subprocess.run([sys.executable, "-c", ENABLE_IN_FRESH_PROCESS + READ],
                          capture_output=True, text=True, timeout=120, check=True)
    read = json.loads(done.stdout.strip().splitlines()[-1])
    assert read == VALUES
