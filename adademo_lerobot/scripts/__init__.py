"""The console entry points (`adademo-*`): each parses its flags and calls the command's function.

They are programs, not the library: the GL backend MuJoCo will render with is picked here, before the command's
modules import MuJoCo (`adademo_lerobot.gl`).
"""

from adademo_lerobot.gl import prefer_loadable_backend

prefer_loadable_backend()
