"""One module per event-file format; :func:`datagen.recording.open_recording` picks."""
