import sys

from polarref.cli import main

sys.exit(main())
