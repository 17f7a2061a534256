"""The ImGui panel (:mod:`.panel`) and one module per section of it (scene, view, particles, selected, edits,
insert, output; their fields in :mod:`.fields`)."""
