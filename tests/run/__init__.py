"""The command line and the shards a day's manifest runs as."""
