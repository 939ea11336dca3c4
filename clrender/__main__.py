import sys

from clrender.cli import main

sys.exit(main())
