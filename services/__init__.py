"""One package per process. No service imports another service's package: they share only
`proto/` (as `tiplog.v1`) and the `tiplog` library."""

import os as _os
import signal as _signal
import threading as _threading

# A child of `tiplog up` (`tiplog.service.SUPERVISED_ENV`) is stopped by its supervisor with
# SIGTERM. The terminal's Ctrl-C reaches the whole process group, and the service ignores it only
# once it has set its handlers: a child or spare still importing would end in a KeyboardInterrupt
# traceback. Ignored from the package's first import instead.
if _os.environ.get("TIPLOG_SUPERVISED") == "1" and _threading.current_thread() is _threading.main_thread():
    _signal.signal(_signal.SIGINT, _signal.SIG_IGN)
