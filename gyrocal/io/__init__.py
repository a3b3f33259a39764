"""The data in and the files out: logs read and checked, blocks, holds, signals, tables, records.
May import: no other folder of gyrocal."""
