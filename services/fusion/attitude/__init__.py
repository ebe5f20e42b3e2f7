"""The six-axis attitude filter (gyroscope and accelerometer alone) and `tiplog fusion attitude`."""
