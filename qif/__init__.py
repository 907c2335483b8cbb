"""QIF 3.0 results output and the ``qifreport`` command line."""

__version__ = "0.1.0"
