"""scratchfab: scratch-based reflection art, from target images to an engraved board."""

__version__ = "0.1.0"
