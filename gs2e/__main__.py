import sys

from gs2e.cli import main

sys.exit(main())
