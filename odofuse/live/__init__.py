"""``odofuse live``: the streaming Localizer as a ROS 2 component (issue 27).

Modules: :mod:`~odofuse.live.rmw` (rmw_zenoh's wire format: key expressions, type hashes,
liveliness tokens, attachment, session config), :mod:`~odofuse.live.transport` (a ROS 2 node
on a Zenoh session), :mod:`~odofuse.live.messages` (ROS messages in and out),
:mod:`~odofuse.live.component` (the Localizer loop: readings in, estimate out, health),
:mod:`~odofuse.live.foxglove_view` (the Foxglove WebSocket view) and
:mod:`~odofuse.live.run` (the command: live, replay). The ``live:`` block is declared in
:mod:`odofuse.declarations.live`.
"""
