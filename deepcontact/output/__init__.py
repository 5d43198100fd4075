"""Outputs that are whole or not there: every file and folder a command writes goes through here.

One module per concern, lower ones never importing higher ones:

- ``names``: the names made beside an output (``.NAME.lock``, ``.NAME.partial-*``, ...);
- ``files``: a single file, written to a temporary name and renamed;
- ``record``: which entries of an output folder its command wrote (``.dc-output.json``);
- ``lock``: one command at a time on an output;
- ``swap``: a folder built beside its place and swapped in by a journalled replacement;
- ``claim``: the rules a command claims its ``-o`` by, ``output_file`` and ``output_folder``;
- ``trees``: folders removed at any depth, private temporary folders swept after a kill.

An interrupted command leaves the complete output or the earlier one, never a half; the next
command on that output finishes or undoes what a killed one left.
"""
from .claim import check_file, check_folder, output_file, output_folder
from .files import (check_replaceable, figure_bytes, make_dir, make_folder_for, new_temporary, open_fd,
                    open_for_write, open_new, write_bytes, write_text)
from .lock import locked
from .names import short_name, temporary_name
from .record import RECORD, InPlace, Owned, check_owned_folder, entries, read_record
from .swap import completed, folder, hold_building, recover, release_building
from .trees import private_folder, remove_tree, remove_tree_quietly

__all__ = ["RECORD", "InPlace", "Owned", "check_file", "check_folder", "check_owned_folder", "check_replaceable",
           "completed", "entries", "figure_bytes", "folder", "hold_building", "locked", "make_dir",
           "make_folder_for", "new_temporary", "open_fd", "open_for_write", "open_new", "output_file",
           "output_folder", "private_folder", "read_record", "recover", "release_building", "remove_tree",
           "remove_tree_quietly", "short_name", "temporary_name", "write_bytes", "write_text"]
