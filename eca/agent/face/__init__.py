"""The ResponsiveFace-style face: flexors, actions, emotions and layered compositing.

- flexors: the flexor set; frame: `FlexorFrame`, one complete flexor vector, and `DONT_CARE`
- emotions: the emotion table of configs/emotions.toml; actions: `Pose`, `Keyframes`, `Envelope`
- head: interruptible head moves; idle: Perlin idle noise; settling: per-flexor settle times
- compositor: the layer stack; model: `FaceModel`, the façade the renderers drive
"""
