"""Proxies that publish entities without the client software (transit: SIRI StopMonitoring)."""
