import sys

from scenelabel.cli import main

sys.exit(main())
