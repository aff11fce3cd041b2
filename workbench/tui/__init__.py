"""The design workbench: a Textual app over ``codev_engine`` (``codev tui``)."""
