import sys

from services.vision.app import main

if __name__ == "__main__":
    sys.exit(main())
