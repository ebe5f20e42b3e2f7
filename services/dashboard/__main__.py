import sys

from services.dashboard.app import main

if __name__ == "__main__":
    sys.exit(main())
