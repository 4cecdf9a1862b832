"""The interactive window: the pyglet adapter that shows a pack's layout and feeds mouse and keys to the App."""
