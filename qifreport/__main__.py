"""``python -m qifreport``: the command line."""

from qifreport.cli import main

main()
