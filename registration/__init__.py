"""Registration: mesh layer, rigid ICP, GB-CICP virtual fixturing, and the simulation toolkit."""

from qifreport.errors import InputError

__all__ = ["InputError"]
