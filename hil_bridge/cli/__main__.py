import sys

from hil_bridge.cli import main

sys.exit(main())
