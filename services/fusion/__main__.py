import sys

from services.fusion.app import main

if __name__ == "__main__":
    sys.exit(main())
