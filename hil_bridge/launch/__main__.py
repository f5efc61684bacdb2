"""``python -m hil_bridge.launch FILE [...]``: the same as ``echoloop launch FILE [...]``."""

import sys

from hil_bridge.cli import main

sys.exit(main(["launch", *sys.argv[1:]]))
