"""The ``cdcr-ctl`` command line."""
