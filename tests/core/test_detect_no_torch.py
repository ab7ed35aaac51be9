"""The detection runtime and the detector CLI modules must not import torch (runtime is onnxruntime only)."""

from __future__ import annotations

import subprocess
import sys


def test_runtime_and_cli_modules_do_not_import_torch() -> None:
    code = (
        "import sys\n"
        "import gldt_core.detect, gldt_core.eval.detection_metrics, gldt_core.detect.video, gldt_core.eval.halmstad_split\n"
        "import gldt_core.cli.train, gldt_core.cli.export, gldt_core.cli.detect, gldt_core.bench.detection\n"
        "from gldt_core.detect import GlobalDetector\n"
        "GlobalDetector(num_threads=1)\n"
        "bad = [m for m in sys.modules if m == 'torch' or m.startswith('torch.') or m.startswith('gldt_core.training')]\n"
        "print(','.join(bad))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == ""
