"""One module per event-file format; :func:`model.data.recording.open_recording` picks."""
