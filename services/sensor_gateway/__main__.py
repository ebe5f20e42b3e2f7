import sys

from services.sensor_gateway.app import main

if __name__ == "__main__":
    sys.exit(main())
