"""`dream` command line: thin wrappers around the library. Every failure is one line on stderr.

One module per command (`robots`, `info`, `overlay`, `calibrate`, `diagnose`, `eval`,
`sample`, `demo`): each turns its options into a frozen request dataclass and runs it;
`app` holds the parser and `main`, `options` the helpers the commands share."""

from dream.cli.app import (
    ENTRY_POINT_GROUP,
    EXIT_BROKEN_PIPE,
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    build_parser,
    main,
)
from dream.cli.calibrate import CalibrateRequest, run_calibrate
from dream.cli.demo import BUNDLED_MODEL, DemoRequest, run_demo
from dream.cli.diagnose import DiagnoseRequest, run_diagnose
from dream.cli.eval import EvalRequest, run_eval
from dream.cli.info import InfoRequest, run_info
from dream.cli.overlay import OverlayRequest, run_overlay
from dream.cli.sample import SampleRequest, run_sample

__all__ = [
    "BUNDLED_MODEL",
    "ENTRY_POINT_GROUP",
    "EXIT_BROKEN_PIPE",
    "EXIT_ERROR",
    "EXIT_INTERRUPTED",
    "CalibrateRequest",
    "DemoRequest",
    "DiagnoseRequest",
    "EvalRequest",
    "InfoRequest",
    "OverlayRequest",
    "SampleRequest",
    "build_parser",
    "main",
    "run_calibrate",
    "run_demo",
    "run_diagnose",
    "run_eval",
    "run_info",
    "run_overlay",
    "run_sample",
]
