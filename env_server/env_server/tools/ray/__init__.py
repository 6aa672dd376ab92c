"""Run env servers as Ray actors across a cluster: `python -m env_server.tools.ray` (see launcher.py).

Importing this package does not import Ray; launcher.py does, with absolute imports, so
`import ray` there is the real Ray, never this package.
"""
