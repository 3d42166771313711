"""The controllers czmpc's MPC is compared against (layer 2: imports the core and `czmpc.pid`, never `sim`).

- `czmpc.peers.nmpc`: nonlinear MPC on the un-inverted model (CasADi/IPOPT), the reference.
- `czmpc.peers.pi`: gain-scheduled PI with anti-windup (the controller and rule of `czmpc.pid`).
- `czmpc.peers.open_loop`: static inversion with no feedback.

The linear MPC peer is `czmpc.OffsetFreeMPC` on a ``kind = "linear"`` model and needs no
module of its own.
"""
