def main():
    print("sarcomere")
