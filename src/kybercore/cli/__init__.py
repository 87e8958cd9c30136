"""The ``kybercore`` command (``main.app``).

Heavy parts (FastAPI, uvicorn, the simulator) are imported by the commands that use them.
"""
