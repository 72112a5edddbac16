"""``python -m cdcr_ctl`` is ``cdcr-ctl``."""

import sys

from cdcr_ctl.cli.main import main

sys.exit(main())
