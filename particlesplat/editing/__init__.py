"""Object edits: grouping particles into objects, moves, named do/undo operations, edit files, insert/export."""
