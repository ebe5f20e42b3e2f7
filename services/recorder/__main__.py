import sys

from services.recorder.app import main

if __name__ == "__main__":
    sys.exit(main())
