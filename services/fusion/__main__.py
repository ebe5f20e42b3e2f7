import sys

from services.fusion.live.app import main

if __name__ == "__main__":
    sys.exit(main())
