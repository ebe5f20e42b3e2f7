import sys

from services.igtlink.app import main

if __name__ == "__main__":
    sys.exit(main())
