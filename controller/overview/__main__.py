from common.plumbing.lifecycle import exit_process
from controller.overview.main import main

exit_process(main())
