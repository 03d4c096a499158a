"""``moegs view``: a local web viewer (viser) for trained expert runs and MoE-GS router folders.

- ``moegs.viewer.render``: what is drawn, as plain functions (viewer pose -> ``Camera``, mode -> image,
  colour maps, colour bars, legends);
- ``moegs.viewer.model``: what is opened (``load_model``: runs or a router folder -> ``ViewModel``);
- ``moegs.viewer.server``: the viser glue (``Viewer``: camera, time slider with play/pause, modes).

viser is an optional dependency (``pip install moegs[viewer]``); only ``server`` imports it.
"""
