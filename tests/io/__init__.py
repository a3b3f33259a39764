"""Reading and writing: the log contract, tables, schemas, unit folders, the block kernels, bad and fuzzed inputs."""
