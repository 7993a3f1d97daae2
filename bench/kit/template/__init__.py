"""The `__method_name__` method for gibench: method.py holds the method and its manual (its docstring)."""
