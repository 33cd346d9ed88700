"""The editor behind ``bezmotion edit``: an editing session of one clip (:class:`EditSession`),
a plain Python object that any front end (the browser editor) drives."""

from bezmotion.editor.session import EditHandle, EditSession, EditState, EditView

__all__ = ["EditHandle", "EditSession", "EditState", "EditView"]
