"""``python -m qifreport``: the command line."""

from qifreport.launch import main

main()
