"""The detection runtime and the detector CLI modules must not import torch (runtime is onnxruntime
only), and nothing at run time imports the export-time code of ``gldt_core.export``."""

from __future__ import annotations

import subprocess
import sys


def test_runtime_and_cli_modules_do_not_import_torch_or_export_code() -> None:
    code = (
        "import sys\n"
        "import gldt_core.detect, gldt_core.detect.video\n"
        "import gldt_core.eval.detection_metrics, gldt_core.eval.halmstad_split\n"
        "import gldt_core.cli.train, gldt_core.cli.export, gldt_core.cli.detect, gldt_core.bench.detection\n"
        "from gldt_core.detect import GlobalDetector, LocalDetector\n"
        "GlobalDetector(num_threads=1)\n"
        "LocalDetector(num_threads=1)\n"
        "def loaded(prefix):\n"
        "    return [m for m in sys.modules if m == prefix or m.startswith(prefix + '.')]\n"
        "bad = loaded('torch') + loaded('gldt_core.training') + loaded('gldt_core.export')\n"
        "print(','.join(bad))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == ""
