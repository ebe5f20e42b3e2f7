"""Time and messages: the runner that orders measurements, rewinds for late frames and
publishes states, and the one adapter from bus/recording messages to measurements."""
