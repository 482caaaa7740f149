"""The core stays pure: `dream` imports neither torch nor the other stages."""

import subprocess
import sys


def test_core_imports_no_torch_and_no_other_stage():
    code = (
        "import sys, dream.cli, dream.calibration, dream.pipeline, dream.io, dream.robot, "
        "dream.overlay, dream.sample, dream.crb\n"
        "bad = [m for m in sys.modules if m.split('.')[0] in "
        "('torch', 'lightning', 'train', 'synth', 'export')]\n"
        "print(bad); sys.exit(1 if bad else 0)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
