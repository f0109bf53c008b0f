"""``python -m hocnet.cli``: the same as the ``hocnet`` command."""

import sys

from hocnet.cli import main

sys.exit(main())
