"""ROS-free pieces shared by the controller core, the plant and the tools: contract, parameter schema, friction law."""
