"""The SAPIEN layer shared by every task: scene, cameras, actor building."""
