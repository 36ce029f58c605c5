"""Object detection: Yolo-Fastest v1.1 read from its darknet files, boxes turned into pixel masks."""
