"""Adapters from simulator suites to the Task contract, one module per suite.

Each backend imports its suite lazily (inside the constructor) so that listing envs
and starting the server stay fast and do not require every suite to be installed.
"""
