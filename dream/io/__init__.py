"""Reading and writing sequences: the DREAM/NDDS layout and the real-data layouts.

`read_sequence` reads any supported layout (`FORMATS`, see `detect_format`) into a
`dream.sequence.Sequence`; `write_dream` writes the DREAM layout (docs/data_format.md) atomically;
`load_image` / `load_mask` fetch a frame's pixels. Every input problem is an `InputError`.
"""

from dream.io.atomic import (
    atomic_directory,
    check_output_file,
    check_output_folder,
    is_temporary,
    make_output_dir,
    outermost_missing,
    remove_temporaries,
    replacing_files,
    staged_directory,
    write_bytes_atomic,
    write_files_atomic,
    write_json_atomic,
)
from dream.io.detect import FORMATS, detect_format
from dream.io.dream_layout.read import read_dream
from dream.io.dream_layout.write import write_dream
from dream.io.franka_offline import read_franka_offline
from dream.io.images import image_size, load_image, load_mask, load_mask_ids
from dream.io.intrinsics import parse_intrinsics_text
from dream.io.maniunicon import read_maniunicon
from dream.io.panda_teleop import read_panda_teleop
from dream.io.read import read_sequence

__all__ = [
    "FORMATS",
    "atomic_directory",
    "check_output_file",
    "check_output_folder",
    "detect_format",
    "image_size",
    "is_temporary",
    "load_image",
    "load_mask",
    "load_mask_ids",
    "make_output_dir",
    "outermost_missing",
    "remove_temporaries",
    "parse_intrinsics_text",
    "read_dream",
    "read_franka_offline",
    "read_maniunicon",
    "read_panda_teleop",
    "read_sequence",
    "replacing_files",
    "staged_directory",
    "write_bytes_atomic",
    "write_dream",
    "write_files_atomic",
    "write_json_atomic",
]
