
from common.plumbing.lifecycle import exit_process

from .main import main

exit_process(main())
