"""Benchmark suites for `evsplat bench`. Each module defines HELP, add_arguments(parser) and
run(args) -> int, prints a table with its baseline measured in the same run, and never fails
on time."""
