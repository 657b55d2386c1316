"""Host side of the stid link: wire decoding, the serial logger (stid-log), MCAP files."""
