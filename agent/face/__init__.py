"""The ResponsiveFace-style face: flexors, actions, emotions and layered compositing."""
