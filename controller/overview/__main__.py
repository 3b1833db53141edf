import sys

from controller.overview.main import main

sys.exit(main())
